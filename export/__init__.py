"""Export session files to community formats (NWB). Analysis layer: imports protocols only."""
