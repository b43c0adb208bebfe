"""Protocols as data and pure functions: configuration, calibration ramps, the randomised
sE schedule and the rE waveforms (steady lead-in plus exponential chirp).

Nothing here talks to a device; every function can be dry-run and unit-tested.
"""
