"""Stand-ins that users run as well as tests: faithful fakes of the vendor libraries.

``testing.fakes`` holds McsUsbNet, CAIO, nidaqmx and a Leptrino emulator, each built from
the vendor's documentation (sources cited in each module). ``fake = true`` in a hardware
configuration runs the real drivers over them; never use them with a participant.
"""
