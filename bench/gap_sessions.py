"""Sessions the gap diagnosis was not written for: clean rigs of other timing conventions,
nuisances that are not model effects, and physiology outside its six candidates.

Every session starts from the simulator's virtual participant (no library effect) run
through the 45-trial protocol, twice: once with an ideal sensor (the participant's force)
and once with its sensor (noise, offset, drift, mains). The sensor's part is the
difference; the generators below transform the participant's force, then the sensor's
part is added back. Nothing here is in the simulator's library: the generators are
written from the physiology and the instrumentation, with shapes and magnitudes drawn per
session.

Rig timing. The simulated stimulator holds each commanded sample (the stimulation lags
the record by half a sample). A rig without that hold is emulated by recording rE moved by
half a sample (the record is then the stimulation itself); other sub-millisecond
conventions likewise.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy import signal

from nmsid.analysis.discretize import fractional_delay
from nmsid.protocols.config import Randomisation
from nmsid.protocols.schedule import make_schedule
from nmsid.protocols.session_file import SessionWriter, Trial
from nmsid.protocols.waveforms import chirp_phase_rad

FS_HZ = 2000.0
STEADY_S = 5.0
CHIRP_S = 10.0
LEVELS = tuple(np.round(np.linspace(0.30, 1.00, 15), 2))

CLEAN = ("clean",)
NUISANCES = ("voluntary_contraction", "spikes", "mains_60Hz", "carrier_alias")
OUTSIDE = ("tremor", "reflex_delayed", "output_saturation", "co_contraction")

#: Rig timing conventions of the clean sessions: the stimulation's delay behind the record.
TIMINGS_S = (0.25e-3, 0.0, 0.6e-3, -0.4e-3)


def chirp_rE():
    n = int(round((STEADY_S + CHIRP_S) * FS_HZ))
    t = np.arange(n) / FS_HZ
    tc = np.clip(t - STEADY_S, 0.0, None)
    return t, np.where(t < STEADY_S, 0.5, 0.5 + 0.5 * np.sin(chirp_phase_rad(tc, 1.0, 10.0,
                                                                                 CHIRP_S)))


def _bandpass_noise(rng, n, f_Hz, width_Hz, rms):
    """A physiological oscillation: white noise through a resonator (AR(2))."""
    r = np.exp(-np.pi * width_Hz / FS_HZ)
    th = 2 * np.pi * f_Hz / FS_HZ
    x = signal.lfilter([1.0], [1.0, -2 * r * np.cos(th), r * r], rng.standard_normal(n + 4000))
    x = x[4000:]
    return rms * x / np.std(x)


class Generator:
    """One session's transformation, its parameters drawn from ``(kind, seed)``."""

    def __init__(self, kind: str, seed: int):
        self.kind = kind
        self.rng = np.random.default_rng([seed, 7, len(kind), sum(map(ord, kind))])
        rng = self.rng
        self.noise_N = float(np.exp(rng.uniform(np.log(0.005), np.log(0.06))))
        self.timing_s = TIMINGS_S[seed % len(TIMINGS_S)] if kind == "clean" else 0.25e-3
        p: dict = {}
        if kind == "voluntary_contraction":
            p["trials"] = sorted(rng.choice(45, size=int(rng.integers(1, 3)), replace=False)
                                 .tolist())
            p["amplitude_N"] = float(rng.uniform(1.0, 4.0))
            p["duration_s"] = float(rng.uniform(1.0, 2.0))
        elif kind == "spikes":
            p["count"] = int(rng.integers(5, 30))
            p["amplitude_N"] = float(rng.uniform(2.0, 10.0))
        elif kind == "mains_60Hz":
            p["mains_N"] = float(rng.uniform(0.05, 0.3))
            p["harmonics"] = [float(rng.uniform(0.1, 0.5)), float(rng.uniform(0.05, 0.3))]
        elif kind == "carrier_alias":
            p["pulse_Hz"] = float(rng.uniform(20.0, 45.0))
            p["amplitude_N"] = float(rng.uniform(0.02, 0.1))
        elif kind == "tremor":
            p["f_Hz"] = float(rng.uniform(8.0, 12.0))
            p["width_Hz"] = float(rng.uniform(0.5, 1.5))
            p["rms_at_sE1_N"] = float(rng.uniform(0.04, 0.12))
        elif kind == "reflex_delayed":
            p["delay_s"] = float(rng.uniform(0.04, 0.08))
            p["gain"] = float(rng.uniform(0.12, 0.3)) * (1 if rng.uniform() < 0.5 else -1)
        elif kind == "output_saturation":
            p["compression_pct"] = float(rng.uniform(10.0, 25.0))
        elif kind == "co_contraction":
            p["gain_N"] = float(rng.uniform(0.3, 1.0))
            p["tau_s"] = float(rng.uniform(0.03, 0.08))
        self.params = p
        self.peak_N = None

    def describe(self) -> str:
        return ", ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}"
                         for k, v in self.params.items())

    def force(self, k: int, t: np.ndarray, rE: np.ndarray, sE: float, f: np.ndarray
              ) -> np.ndarray:
        """Trial ``k``'s force from the participant's own force ``f`` (ideal sensor)."""
        p, rng, kind = self.params, self.rng, self.kind
        rest = float(np.mean(f[int(2 * FS_HZ):int(STEADY_S * FS_HZ)]))
        if kind == "voluntary_contraction" and k in p["trials"]:
            t0 = float(rng.uniform(STEADY_S, STEADY_S + CHIRP_S - p["duration_s"]))
            m = (t >= t0) & (t < t0 + p["duration_s"])
            f = f.copy()
            f[m] += p["amplitude_N"] * np.sin(np.pi * (t[m] - t0) / p["duration_s"]) ** 2
        elif kind == "spikes":
            f = f.copy()
            for _ in range(rng.poisson(p["count"] / 45.0)):
                i = int(rng.integers(0, len(f) - 3))
                f[i:i + int(rng.integers(1, 4))] += p["amplitude_N"] * rng.choice([-1, 1])
        elif kind == "mains_60Hz":
            ph = rng.uniform(0, 2 * np.pi, 3)
            f = f + p["mains_N"] * (np.sin(2 * np.pi * 60 * t + ph[0])
                                    + p["harmonics"][0] * np.sin(2 * np.pi * 120 * t + ph[1])
                                    + p["harmonics"][1] * np.sin(2 * np.pi * 180 * t + ph[2]))
        elif kind == "carrier_alias":
            # a narrow artefact at every stimulation pulse (0.2 ms), sampled at 2 kHz:
            # its harmonics above 1 kHz fold into the band
            tp = np.arange(rng.uniform(0, 1 / p["pulse_Hz"]), t[-1], 1 / p["pulse_Hz"])
            a = np.zeros_like(f)
            idx = np.searchsorted(t, tp)
            for ti, i in zip(tp, idx, strict=True):
                for j in range(max(0, i - 2), min(len(t), i + 3)):
                    a[j] += np.exp(-0.5 * ((t[j] - ti) / 1e-4) ** 2)
            f = f + p["amplitude_N"] * sE * a
        elif kind == "tremor":
            fk = p["f_Hz"] + rng.normal(0, 0.4)
            f = f + sE * _bandpass_noise(rng, len(f), fk, p["width_Hz"], p["rms_at_sE1_N"])
        elif kind == "reflex_delayed":
            resp = f - rest
            f = f + p["gain"] * fractional_delay(resp, p["delay_s"] * FS_HZ)
        elif kind == "output_saturation":
            if self.peak_N is None:   # the compression is set on the first trial's peak
                self.peak_N = max(float(np.max(np.abs(f))), 1e-6)
            c = p["compression_pct"] / 100.0
            # tanh compression: a force at the first trial's peak is reduced by c
            x = np.linspace(0.1, 20.0, 2000)
            s = self.peak_N * x[np.argmin(np.abs(x * np.tanh(1 / x) - (1 - c)))]
            f = s * np.tanh(f / s)
        elif kind == "co_contraction":
            both = 4 * rE * (1 - rE)          # 1 when both muscles share the drive equally
            b = np.exp(-1 / (p["tau_s"] * FS_HZ))
            f = f + p["gain_N"] * sE * signal.lfilter([1 - b], [1, -b], both - 1.0)
        return f

    def record_rE(self, rE: np.ndarray) -> np.ndarray:
        """The rE the rig records: the stimulator holds samples (0.25 ms behind the
        command); a rig whose stimulation lags the record by ``timing_s`` records the
        command moved by the difference."""
        return fractional_delay(rE, (0.25e-3 - self.timing_s) * FS_HZ)


def simulate(participant, path, kind: str, seed: int) -> Generator:
    """Write one session of ``kind`` (see module) to ``path``; returns its generator."""
    from nmsid.sim_backends.sensor import SensorModel
    from nmsid.sim_backends.simulation import ParticipantSimulator

    gen = Generator(kind, seed)
    sensor = dataclasses.replace(participant.sensor, noise_N=gen.noise_N)
    if kind == "mains_60Hz":
        sensor = dataclasses.replace(sensor, mains_N=0.0)
    real = dataclasses.replace(participant, sensor=sensor)
    ideal = dataclasses.replace(participant, sensor=SensorModel.ideal())
    sims = [ParticipantSimulator(p, FS_HZ) for p in (ideal, real)]
    cal = participant.calibration
    schedule = make_schedule(LEVELS, 3, (Randomisation.BLOCKS, Randomisation.FULL)[seed % 2],
                             seed)
    w = SessionWriter.create(path, participant=participant.code, seed=seed, backend="sim")
    w.write_calibration(cal.as_session_calibration())
    t, rE = chirp_rE()
    for k, planned in enumerate(schedule):
        sE = planned.sE
        I_e = cal.Iemin_mA + rE * sE * (cal.Iemax_mA - cal.Iemin_mA)
        I_f = cal.Ifmin_mA + (1.0 - rE) * sE * (cal.Ifmax_mA - cal.Ifmin_mA)
        f_ideal = sims[0].simulate(I_e, I_f).force_N
        block = sims[1].simulate(I_e, I_f)
        sensor_part = block.force_N - f_ideal
        force = gen.force(k, t, rE, float(sE), f_ideal) + sensor_part
        w.append_trial(Trial(sE=float(sE), repeat=planned.repeat, fs_Hz=FS_HZ,
                             rE=gen.record_rE(rE), I_ext_mA=I_e, I_flex_mA=I_f, force_N=force,
                             steady_s=STEADY_S, chirp_s=CHIRP_S,
                             extra_attrs={"cumulative_stim_s":
                                          block.cumulative_stim_s - len(rE) / FS_HZ}))
        for s in sims:
            s.advance_quiet(int(20.0 * FS_HZ))
    return gen
