"""The experiment controller: protocol engine, safety interlock, session logging, GUI, CLI.

The engine executes protocols (``protocols``) through driver interfaces (``drivers``),
checks every waveform against the current ceilings before it reaches a stimulator, stops
output at once on any fault or emergency stop, and writes each trial to the HDF5 session
file (``protocols.session_file``) as the session goes. The ``nmsid`` command lives in ``rig.cli``.
"""
