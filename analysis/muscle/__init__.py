"""The physiological twin: two Hill-type muscles on the isometric elbow (issue 20).

- :mod:`~nmsid.analysis.muscle.dynamics`: the equations, simulated in batches;
- :mod:`~nmsid.analysis.muscle.literature`: literature values, bounds and weak priors;
- :mod:`~nmsid.analysis.muscle.fit`: fitting a session (all sE at once) with uncertainties;
- :mod:`~nmsid.analysis.muscle.candidate`: the twin as a candidate of the gap diagnosis.
"""
