"""Study-wide analysis: many sessions identified and diagnosed as Dask tasks, then the group
report. Sits above analysis, below rig."""
