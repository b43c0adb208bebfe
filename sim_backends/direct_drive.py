"""Drive the simulated devices directly, without the engine (tests and benchmarks).

The helpers build a trial's currents from the paper's eqs. 1-4 and run one waveform
through the device interfaces in the order the engine uses (load, arm, triggered
acquisition start, stimulator start, read chunks).
"""

from __future__ import annotations

import numpy as np

from nmsid.drivers.interfaces import CheckedWaveform
from nmsid.protocols.waveforms import currents_mA

FS_HZ = 2000.0


def currents_for(cal, sE: float, rE: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Extensor / flexor currents of eqs. 1-4 inverted (I_e = rE sE, I_f = (1-rE) sE)."""
    return currents_mA(rE, sE, cal.Iemin_mA, cal.Iemax_mA, cal.Ifmin_mA, cal.Ifmax_mA)


def chirp_rE(fs_Hz: float = FS_HZ, steady_s: float = 5.0, chirp_s: float = 10.0,
             f0: float = 1.0, f1: float = 10.0) -> np.ndarray:
    t = np.arange(int(round((steady_s + chirp_s) * fs_Hz))) / fs_Hz
    tc = np.clip(t - steady_s, 0.0, None)
    k = np.log(f1 / f0) / chirp_s
    phase = 2 * np.pi * f0 * (np.exp(k * tc) - 1.0) / k
    return np.where(t < steady_s, 0.5, 0.5 + 0.5 * np.sin(phase))


def waveform(I_e, I_f, fs_Hz: float = FS_HZ, ceiling_mA: float = 16.0) -> CheckedWaveform:
    return CheckedWaveform(np.asarray(I_e, float), np.asarray(I_f, float), fs_Hz, 1000.0,
                           ceiling_mA, ceiling_mA)


def run_waveform(rig, wf: CheckedWaveform, n: int | None = None, *, timeout_s: float = 0.05,
                 on_chunk=None, max_reads: int = 100000):
    """Load, arm, start acquisition (triggered) and stimulator, read ``n`` samples.

    Returns (force_N, chunks). ``on_chunk(rig, chunk)`` may return True to stop reading.
    """
    n = wf.n_samples if n is None else n
    stim, acq = rig.stimulator, rig.acquisition
    stim.load(wf)
    stim.arm()
    acq.start(n, triggered=True)
    stim.start()
    chunks = []
    got = 0
    for _ in range(max_reads):
        if got >= n:
            break
        c = acq.read(timeout_s)
        if c is None:
            if on_chunk is not None and on_chunk(rig, None):
                break
            continue
        chunks.append(c)
        got = c.start_index + c.n
        if on_chunk is not None and on_chunk(rig, c):
            break
    acq.stop()
    force = np.full(n, np.nan)
    for c in chunks:
        force[c.start_index:c.start_index + c.n] = c.force_N[:max(0, min(c.n, n - c.start_index))]
    return force, chunks


def ramp_thresholds(rig, muscle: str, step_mA: float = 0.5, hold_s: float = 1.0,
                    ceiling_mA: float = 16.0) -> tuple[float | None, float | None]:
    """A plain calibration ramp through the devices (independent of ``protocols``).

    Each step is held ``hold_s``; its force is the mean of the hold's second half minus
    the mean of a zero-current hold run first. Returns (Imin, Imax): the first steps whose
    force (sign-corrected: the flexor pulls) reaches the participant's Fmin / Fmax.
    """
    fs = rig.acquisition.fs_Hz
    cal = rig.participant.calibration
    n = int(round(hold_s * fs))
    zero = np.zeros(n)
    base, _ = run_waveform(rig, waveform(zero, zero, fs))
    baseline = float(np.mean(base[n // 2:]))
    sign = 1.0 if muscle == "ext" else -1.0
    imin = imax = None
    for k in range(1, int(ceiling_mA / step_mA + 1e-9) + 1):
        on = np.full(n, k * step_mA)
        wf = waveform(on, zero, fs) if muscle == "ext" else waveform(zero, on, fs)
        force, _ = run_waveform(rig, wf)
        f = sign * (float(np.mean(force[n // 2:])) - baseline)
        if imin is None and f >= cal.Fmin_N:
            imin = k * step_mA
        if f >= cal.Fmax_N:
            imax = k * step_mA
            break
    return imin, imax
