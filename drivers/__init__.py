"""Hardware interfaces and real drivers.

``drivers.interfaces`` declares what the engine needs from a stimulator, a force
acquisition chain and an emergency-stop input (small ``typing.Protocol`` classes). The real
drivers (MCS STG4002, Contec AI-1608AY-USB, NI DAQ, Leptrino USB, E-stop switch) implement
them; the simulated rig in ``sim_backends`` implements the same ones. Importing this package
never needs a vendor library: each driver loads its library only when it is used.
"""
