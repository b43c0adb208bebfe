"""Session files -> the arrays the gap diagnosis works on.

One signal path with identification: the force and the drive ``rE - 0.5`` pass through
the same filters as in :mod:`nmsid.analysis.preprocess`
(:func:`nmsid.analysis.preprocess.smooth_and_lowpass` with the settings of
:class:`nmsid.analysis.settings.IdentificationSettings`: Savitzky-Golay order 3, window 41,
zero-phase Butterworth low-pass at 25 Hz), rE is moved by the same input timing
(:mod:`nmsid.analysis.input_timing`: estimated per session by default, or fixed by the setting
``input_timing``), and the models run at the identification's fit rate (``fit_fs_Hz``, 200 Hz) with
the same hold correction (:func:`nmsid.analysis.discretize.smooth_hold_input`). The analysis window
(t >= steady_s) is evaluated at every ``eval_step``-th simulation sample (100 Hz: the force has next
to nothing above 25 Hz left, and 3 x 10 Hz stays below Nyquist). The offset and the linear
trend (the paper's detrend) are not subtracted here: every model carries them as
per-trial nuisance terms, so that the nominal and the augmented models are scored on the
same footing. The simulation starts ``lead_s`` before the window, so that any transient
of a delay or lag has settled when the window starts.

Trials excluded upstream (quality control: a mapping trial name -> reason) are left out
and listed, like aborted and non-finite trials.

Cumulative stimulation time is taken from the trial attribute ``cumulative_stim_s`` when a
writer stored it, otherwise it is the summed length of all earlier trials (completed or
aborted: an aborted trial stimulated too), in file order ``t001, t002, ...``.
"""

from __future__ import annotations

import functools
import logging
import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from nmsid.analysis.discretize import smooth_hold_input
from nmsid.analysis.gap.errors import GapInputError
from nmsid.analysis.input_timing import TimingEstimate, estimate_session_timing
from nmsid.analysis.preprocess import delay_input, smooth_and_lowpass
from nmsid.analysis.settings import IdentificationSettings
from nmsid.protocols.joints import recorded_quantity
from nmsid.protocols.session_file import Session, read_session
from nmsid.protocols.waveforms import chirp_frequency_Hz, chirp_phase_rad

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class PreprocessSettings:
    """How force and drive are prepared: the identification's signal settings plus the
    diagnosis's evaluation grid (see module)."""

    signal: IdentificationSettings = field(default_factory=IdentificationSettings)
    """Filters, fit rate and input timing, shared with identification."""
    eval_step: int = 2
    """Evaluate every this many simulation samples (100 Hz at the 200 Hz fit rate)."""
    lead_s: float = 1.0
    edge_s: float = 0.3
    """Left out at the end of each trial: the zero-phase filters' end transients differ
    between the force (a response) and the drive, and would look like a model error."""

    @property
    def lowpass_Hz(self) -> float:
        return float(self.signal.lowpass_Hz or 25.0)

    @property
    def lowpass_order(self) -> int:
        return int(self.signal.butter_order)

    @property
    def fs_sim_Hz(self) -> float:
        return float(self.signal.fit_fs_Hz or 200.0)

    @property
    def fs_eval_Hz(self) -> float:
        return self.fs_sim_Hz / self.eval_step


@dataclass
class TrialInfo:
    """Where one completed trial sits in its session."""

    name: str
    order: int
    """1-based position among all trials of the file (aborted ones included)."""
    sE: float
    repeat: int
    level: int
    """Index into :attr:`GapData.sE_levels`."""
    cum_stim_s: float
    """Cumulative stimulation time at the start of the analysis window, s."""


@dataclass
class GapData:
    """One session, ready for fitting: every array has one row per completed trial."""

    path: str
    participant: str
    settings: PreprocessSettings
    fs_raw_Hz: float
    sE_levels: np.ndarray
    trials: list[TrialInfo]
    y_N: np.ndarray
    """(n_trials, n_eval) filtered force in the window at ``fs_eval_Hz``."""
    drive_raw: np.ndarray
    """(n_trials, n_raw) filtered ``rE - 0.5`` at the raw rate, from ``lead_s`` before the
    window (used for delays)."""
    drive_sim: np.ndarray
    """(n_trials, n_sim) filtered ``rE - 0.5`` at ``fs_sim_Hz``."""
    rE_sim: np.ndarray
    """(n_trials, n_sim) unfiltered commanded rE at ``fs_sim_Hz`` (recruitment models)."""
    d_eval: np.ndarray
    """(n_trials, n_eval) commanded deviation ``rE - 0.5`` at the evaluation samples."""
    t_eval_s: np.ndarray
    """(n_eval,) time since the chirp started."""
    f_inst_Hz: np.ndarray
    """(n_eval,) instantaneous chirp frequency (time maps to frequency)."""
    phase_eval_rad: np.ndarray
    """(n_eval,) chirp phase."""
    chirp_f0_Hz: float
    chirp_f1_Hz: float
    chirp_s: float
    steady_s: float
    n_lead_sim: int
    sim_step: int
    """Evaluation sample k is simulation sample ``n_lead_sim + k * sim_step``."""
    skipped: list[str] = field(default_factory=list)
    timing: TimingEstimate | None = None
    """The input timing applied to rE (estimated or fixed, see module)."""
    excluded: dict = field(default_factory=dict)
    """Trials left out because they were excluded upstream: name -> reason."""
    steady_N: np.ndarray | None = None
    """(n_trials, n_lead) the same lead-in force after offset and trend, at the evaluation
    rate (the noise as it is: its spectrum and correlation)."""
    steady_noise_N2: np.ndarray | None = None
    """(n_trials,) mean square of the filtered force in the steady lead-in (rE = 0.5, last
    3 s before the chirp but 0.3 s) after offset and trend: the sensor's noise floor, free
    of any model error (NaN if the lead-in is shorter than 1 s)."""
    measured: tuple[str, str, str] = ("elbow", "force", "N")
    """``(joint, quantity, unit)`` the session records (:func:`nmsid.protocols.joints.
    recorded_quantity`): ``y_N`` and every ``_N`` figure are in that unit."""

    @property
    def n_trials(self) -> int:
        return len(self.trials)

    @property
    def level(self) -> np.ndarray:
        return np.array([t.level for t in self.trials], dtype=int)

    @property
    def repeat(self) -> np.ndarray:
        return np.array([t.repeat for t in self.trials], dtype=int)

    @property
    def cum_stim_s(self) -> np.ndarray:
        return np.array([t.cum_stim_s for t in self.trials], dtype=float)

    @property
    def order(self) -> np.ndarray:
        return np.array([t.order for t in self.trials], dtype=int)

    @property
    def fs_sim_Hz(self) -> float:
        return self.fs_raw_Hz / self.raw_per_sim

    @property
    def raw_per_sim(self) -> int:
        return int(round(self.fs_raw_Hz / self.settings.fs_sim_Hz))

    @property
    def fs_eval_Hz(self) -> float:
        return self.fs_sim_Hz / self.sim_step

    def subset(self, rows) -> GapData:
        """The same session restricted to some trials (rows in this object's order)."""
        rows = np.asarray(rows, dtype=int)
        return GapData(
            path=self.path, participant=self.participant, settings=self.settings,
            fs_raw_Hz=self.fs_raw_Hz, sE_levels=self.sE_levels,
            trials=[self.trials[i] for i in rows], y_N=self.y_N[rows],
            drive_raw=self.drive_raw[rows], drive_sim=self.drive_sim[rows],
            rE_sim=self.rE_sim[rows], d_eval=self.d_eval[rows], t_eval_s=self.t_eval_s,
            f_inst_Hz=self.f_inst_Hz, phase_eval_rad=self.phase_eval_rad,
            chirp_f0_Hz=self.chirp_f0_Hz, chirp_f1_Hz=self.chirp_f1_Hz,
            chirp_s=self.chirp_s, steady_s=self.steady_s, n_lead_sim=self.n_lead_sim,
            sim_step=self.sim_step, skipped=self.skipped, timing=self.timing,
            excluded=self.excluded,
            steady_N=None if self.steady_N is None else self.steady_N[rows],
            steady_noise_N2=None if self.steady_noise_N2 is None else self.steady_noise_N2[rows],
            measured=self.measured)


def _filter_chain(x: np.ndarray, fs_Hz: float, s: PreprocessSettings) -> np.ndarray:
    """The identification's Savitzky-Golay and low-pass, along the last axis."""
    return smooth_and_lowpass(x, fs_Hz, s.signal)


#: The trial datasets the diagnosis reads (currents, wrench and sync are not needed).
GAP_DATASETS = ("rE", "force_N")


def load_session(session, settings: PreprocessSettings | None = None, *,
                 excluded: Mapping[str, str] | None = None) -> GapData:
    """Pre-process the completed trials of one session (read here if given as a path).

    Parameters
    ----------
    session : path-like or protocols.session_file.Session
        An ``nmsid-session`` HDF5 file (only :data:`GAP_DATASETS` are read), or a session
        the caller has read already (with at least those datasets): a command reads its
        file once and passes the session down.
    settings : PreprocessSettings, optional
    excluded : dict, optional
        Trials excluded upstream (name -> reason): left out and listed.

    Raises
    ------
    GapInputError
        No usable trials, mixed sampling rates or chirp settings, or a window too short.
    """

    s = settings or PreprocessSettings()
    if not isinstance(session, Session):
        session = read_session(session, datasets=GAP_DATASETS)
    data = prepare_trials(session.trials, path=str(session.path),
                          participant=session.participant, settings=s, excluded=excluded)
    data.measured = recorded_quantity(session.attrs)
    return data


#: The lead-in noise is measured above this frequency (a baseline drift lies below; the
#: chirp starts at 1 Hz), by subtracting a centred moving average of 1 / (2 f) s.
NOISE_HIGHPASS_HZ = 1.0


def _highpass(x: np.ndarray, fs_Hz: float) -> np.ndarray:
    """``x`` minus its centred moving average over ``1 / (2 NOISE_HIGHPASS_HZ)`` s (the
    'valid' part only): what a drift below ~1 Hz leaves of a lead-in is a few percent."""
    w = max(3, int(round(fs_Hz / (2 * NOISE_HIGHPASS_HZ))) | 1)
    if len(x) <= w:
        return x - np.mean(x)
    ma = np.convolve(x, np.ones(w) / w, mode="valid")
    h = w // 2
    return x[h:len(x) - h] - ma


@functools.lru_cache(maxsize=32)
def _kept_by_drift_filter(fs_Hz: float, s: PreprocessSettings, step_raw: int) -> float:
    """Share of white sensor noise's power, after the force's filter chain, that
    :func:`_highpass` keeps (60 s of seeded white noise at the raw rate: deterministic)."""
    rng = np.random.default_rng(20261128)
    x = _filter_chain(rng.standard_normal(int(60 * fs_Hz)), fs_Hz, s)[::step_raw]
    x = x[len(x) // 20: -len(x) // 20]                  # the filter's edges aside
    return float(np.mean(_highpass(x, fs_Hz / step_raw) ** 2) / np.mean(x ** 2))


def _drift_robust_power(seg: np.ndarray, fs_Hz: float, kept: float) -> float:
    """The lead-in's noise power robust to a baseline drift: the power above
    :data:`NOISE_HIGHPASS_HZ`, scaled back by the share of filtered white noise kept there.
    A linear detrend alone left a wandering baseline in the estimate (issue 40: a drift
    inflated the noise to 15.6 % of the response and hid a significant gap)."""
    if not (math.isfinite(kept) and kept > 0):
        tt = np.arange(len(seg), dtype=float)
        res = seg - np.polyval(np.polyfit(tt, seg, 1), tt)
        return float(np.mean(res ** 2))
    return float(np.mean(_highpass(seg, fs_Hz) ** 2)) / kept


def _cumulative_stim(trials) -> list[float]:
    out, total = [], 0.0
    for t in trials:
        stored = t.extra_attrs.get("cumulative_stim_s") if t.extra_attrs else None
        try:
            stored = float(np.asarray(stored)) if stored is not None else None
        except (TypeError, ValueError):
            stored = None
        out.append(stored if stored is not None and np.isfinite(stored) else total)
        total += t.n_samples / t.fs_Hz
    return out


def prepare_trials(trials, *, path: str = "<memory>", participant: str = "",
                   settings: PreprocessSettings | None = None,
                   excluded: Mapping[str, str] | None = None,
                   timing: TimingEstimate | None = None) -> GapData:
    """Pre-process a list of :class:`nmsid.protocols.session_file.Trial` (file order) for the
    diagnosis.

    See :func:`load_session`. ``timing``: use this input timing instead of the settings'
    (e.g. a simulated session compared with a measured one gets the measured timing).
    """
    s = settings or PreprocessSettings()
    cum = _cumulative_stim(trials)
    usable, skipped = [], []
    excluded = {str(k): str(v) for k, v in (excluded or {}).items()}
    left_out = {}
    for k, t in enumerate(trials):
        if (t.name or f"t{k + 1:03d}") in excluded:
            left_out[t.name or f"t{k + 1:03d}"] = excluded[t.name or f"t{k + 1:03d}"]
            continue
        if not t.completed:
            skipped.append(f"{t.name or k + 1}: aborted ({t.abort_reason or 'no reason'})")
            continue
        if not (np.all(np.isfinite(t.force_N)) and np.all(np.isfinite(t.rE))):
            skipped.append(f"{t.name or k + 1}: NaN or infinite samples")
            continue
        usable.append((k, t))
    if not usable:
        raise GapInputError(f"{path}: no completed trial with finite force and rE; the gap "
                            "diagnosis needs completed trials of at least two repeats per sE")
    first = usable[0][1]
    keys = ("fs_Hz", "steady_s", "chirp_s", "chirp_f0_Hz", "chirp_f1_Hz")
    for _, t in usable:
        for key in keys:
            if not math.isclose(getattr(t, key), getattr(first, key), rel_tol=1e-9):
                raise GapInputError(
                    f"{path}: trial {t.name} has {key} = {getattr(t, key)!r} but trial "
                    f"{first.name} has {getattr(first, key)!r}; one diagnosis needs one "
                    "protocol (split the file or run the sessions separately)")
    fs = float(first.fs_Hz)
    raw_per_sim = int(round(fs / s.fs_sim_Hz))
    fs_sim = fs / raw_per_sim
    sim_step = int(round(fs_sim / s.fs_eval_Hz))
    if timing is None:
        timing = estimate_session_timing([t for _, t in usable], s.signal)
    if raw_per_sim < 1 or sim_step < 1 or fs < 4 * s.lowpass_Hz:
        raise GapInputError(f"{path}: fs_Hz = {fs:g} is too low for the gap diagnosis "
                            f"(needs at least {4 * s.lowpass_Hz:g} Hz)")
    i_win = int(round(first.steady_s * fs))
    lead = min(int(round(s.lead_s * fs_sim)) * raw_per_sim, i_win)
    lead -= lead % raw_per_sim
    n_min = min(t.n_samples for _, t in usable)
    n_win_raw = n_min - i_win - int(round(s.edge_s * fs))
    step_raw = raw_per_sim * sim_step
    n_eval = n_win_raw // step_raw
    if n_eval * step_raw / fs < 2.0:
        raise GapInputError(f"{path}: the analysis window (t >= steady_s = "
                            f"{first.steady_s:g} s) is shorter than 2 s")
    n_raw_used = lead + n_eval * step_raw
    rows_y, rows_draw, steady, steady_rows = [], [], [], []
    a_st = int(round(max(0.5, first.steady_s - 3.3) * fs))
    b_st = int(round((first.steady_s - 0.3) * fs))
    kept = _kept_by_drift_filter(fs, s, step_raw) if b_st - a_st >= fs else float("nan")
    for _, t in usable:
        force = _filter_chain(np.asarray(t.force_N, float)[:n_min], fs, s)
        rows_y.append(force[i_win: i_win + n_eval * step_raw: step_raw])
        if b_st - a_st >= fs:
            seg = force[a_st:b_st:step_raw]
            tt = np.arange(len(seg), dtype=float)
            res = seg - np.polyval(np.polyfit(tt, seg, 1), tt)
            steady.append(_drift_robust_power(seg, fs / step_raw, kept))
            steady_rows.append(res)
        else:
            steady.append(float("nan"))
        rows_draw.append(np.asarray(t.rE, float)[:n_min])
    rE_full = delay_input(np.vstack(rows_draw), timing.delay_s, fs)
    drive_full = _filter_chain(rE_full - 0.5, fs, s)
    window = slice(i_win - lead, i_win - lead + n_raw_used)
    drive_raw = drive_full[:, window]
    rE_raw = rE_full[:, window]
    levels = np.array(sorted({round(float(t.sE), 10) for _, t in usable}))
    infos = []
    for k, t in usable:
        level = int(np.argmin(np.abs(levels - float(t.sE))))
        infos.append(TrialInfo(name=t.name or f"t{k + 1:03d}", order=k + 1, sE=float(t.sE),
                               repeat=int(t.repeat), level=level,
                               cum_stim_s=cum[k] + first.steady_s))
    t_eval = np.arange(n_eval) * step_raw / fs
    d_eval = rE_raw[:, lead::step_raw][:, :n_eval] - 0.5
    return GapData(
        path=path, participant=participant, settings=s, fs_raw_Hz=fs, sE_levels=levels,
        trials=infos, y_N=np.vstack(rows_y), drive_raw=drive_raw,
        drive_sim=smooth_hold_input(drive_raw[:, ::raw_per_sim]),
        rE_sim=rE_raw[:, ::raw_per_sim].copy(),
        d_eval=d_eval, t_eval_s=t_eval,
        f_inst_Hz=chirp_frequency_Hz(t_eval, first.chirp_f0_Hz, first.chirp_f1_Hz,
                                     first.chirp_s),
        phase_eval_rad=chirp_phase_rad(t_eval, first.chirp_f0_Hz, first.chirp_f1_Hz,
                                       first.chirp_s),
        chirp_f0_Hz=float(first.chirp_f0_Hz), chirp_f1_Hz=float(first.chirp_f1_Hz),
        chirp_s=float(first.chirp_s), steady_s=float(first.steady_s),
        n_lead_sim=lead // raw_per_sim, sim_step=sim_step, skipped=skipped, timing=timing,
        excluded=left_out,
        steady_N=np.vstack(steady_rows) if len(steady_rows) == len(usable) else None,
        steady_noise_N2=np.array(steady))
