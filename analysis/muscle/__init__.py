"""The physiological twin: two Hill-type muscles on the isometric elbow (issue 20).

- :mod:`~analysis.muscle.dynamics`: the equations, simulated in batches;
- :mod:`~analysis.muscle.literature`: literature values, bounds and weak priors;
- :mod:`~analysis.muscle.fit`: fitting a session (all sE at once) with uncertainties;
- :mod:`~analysis.muscle.candidate`: the twin as a candidate of the gap diagnosis.
"""
