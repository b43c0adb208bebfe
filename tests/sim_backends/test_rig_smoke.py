"""The simulated rig runs a trial through the device interfaces, aligned to the trigger."""

import numpy as np

from nmsid.drivers.interfaces import (
    EStopInput,
    ForceAcquisition,
    RigDevices,
    Stimulator,
    StimulatorState,
)
from nmsid.sim_backends import make_sim_rig
from nmsid.sim_backends.direct_drive import chirp_rE, currents_for, run_waveform, waveform


def test_rig_implements_the_interfaces():
    rig = make_sim_rig()
    assert isinstance(rig, RigDevices) and rig.backend == "sim"
    assert isinstance(rig.stimulator, Stimulator)
    assert isinstance(rig.acquisition, ForceAcquisition)
    assert isinstance(rig.estop, EStopInput)
    caps = rig.stimulator.capabilities()
    assert caps.n_channels == 2 and caps.max_current_mA == 16.0
    assert caps.resolution_mA == 0.001


def test_one_trial_end_to_end(ideal_participant):
    rig = make_sim_rig(ideal_participant)
    rig.stimulator.connect()
    rE = chirp_rE()
    I_e, I_f = currents_for(ideal_participant.calibration, 0.6, rE)
    force, chunks = run_waveform(rig, waveform(I_e, I_f))
    assert chunks[0].start_index == 0
    starts = [c.start_index for c in chunks]
    assert starts == sorted(starts) and all(c.sync is not None for c in chunks)
    assert not np.isnan(force).any()
    # the clock advanced by exactly the trial
    assert abs(rig.clock.monotonic_s() - 15.0) < 1e-9
    assert rig.stimulator.status().state is StimulatorState.STOPPED
    assert rig.max_sent_mA == (np.floor(I_e.max() * 1000) / 1000,
                               np.floor(I_f.max() * 1000) / 1000)
