"""Simulated sessions for the gap benchmark: the virtual participant of ``sim_backends``
driven trial by trial with the protocol's waveforms, written as session files.

This drives :class:`sim_backends.simulation.ParticipantSimulator` directly (what the
engine's simulated devices do underneath), which keeps 45-trial sessions at a few seconds.
"""

from __future__ import annotations

import numpy as np

from protocols.config import Randomisation
from protocols.schedule import make_schedule
from rig.session_file import SessionWriter, Trial

FS_HZ = 2000.0
STEADY_S = 5.0
CHIRP_S = 10.0
LEVELS = tuple(np.round(np.linspace(0.30, 1.00, 15), 2))


def chirp_rE(fs_Hz=FS_HZ, steady_s=STEADY_S, chirp_s=CHIRP_S, f0=1.0, f1=10.0):
    from protocols.waveforms import chirp_phase_rad
    n = int(round((steady_s + chirp_s) * fs_Hz))
    t = np.arange(n) / fs_Hz
    tc = np.clip(t - steady_s, 0.0, None)
    return np.where(t < steady_s, 0.5, 0.5 + 0.5 * np.sin(chirp_phase_rad(tc, f0, f1,
                                                                            chirp_s)))


def simulate_session(participant, path, *, seed: int = 0, rest_s: float = 20.0,
                     randomisation: Randomisation = Randomisation.BLOCKS,
                     levels=LEVELS, repeats: int = 3) -> str:
    """Run the identification schedule on ``participant`` and write ``path``.

    Parameters
    ----------
    participant : sim_backends.VirtualParticipant
    path : path-like
        New session file.
    seed : int
        Schedule seed.
    rest_s : float
        Rest between trials (no stimulation; the baseline keeps wandering).
    """
    from sim_backends.simulation import ParticipantSimulator

    sim = ParticipantSimulator(participant, FS_HZ)
    cal = participant.calibration
    schedule = make_schedule(levels, repeats, randomisation, seed)
    w = SessionWriter.create(path, participant=participant.code, seed=seed, backend="sim")
    w.write_calibration(cal.as_session_calibration())
    rE = chirp_rE()
    for planned in schedule:
        sE = planned.sE
        t_session_s = sim.cursor / FS_HZ
        I_e = cal.Iemin_mA + rE * sE * (cal.Iemax_mA - cal.Iemin_mA)
        I_f = cal.Ifmin_mA + (1.0 - rE) * sE * (cal.Ifmax_mA - cal.Ifmin_mA)
        block = sim.simulate(I_e, I_f)
        w.append_trial(Trial(sE=float(sE), repeat=planned.repeat, fs_Hz=FS_HZ, rE=rE,
                             I_ext_mA=I_e, I_flex_mA=I_f, force_N=block.force_N,
                             steady_s=STEADY_S, chirp_s=CHIRP_S,
                             extra_attrs={"cumulative_stim_s":
                                          block.cumulative_stim_s - len(rE) / FS_HZ,
                                          "t_session_s": t_session_s}))
        sim.advance_quiet(int(rest_s * FS_HZ))
    return str(path)
