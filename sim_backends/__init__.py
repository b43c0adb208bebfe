"""The simulated rig: a virtual participant (two muscles, second-order dynamics whose
parameters depend on sE, sensor noise, optional unmodelled effects) behind the same device
interfaces as the hardware, with a real-time and an as-fast-as-possible clock and
scriptable fault injection.
"""
