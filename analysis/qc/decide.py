"""The decision per trial: ``used``, ``repaired`` or ``excluded``, with reasons and spans.

Rules (every threshold in :class:`nmsid.analysis.qc.QCSettings`):

* aborted trials are not judged here (identification already skips them);
* a non-finite commanded rE, a long non-finite, stalled or clipped stretch inside the
  analysed window, too much to bridge, or lead-in noise far above the session's: excluded;
* isolated spikes and short non-finite gaps: bridged by linear interpolation (repaired);
* a baseline jump (the trial's difference from its repeats steps and stays): the step is
  removed from the jump on (repaired);
* a response the other repeats do not share inside the analysed window: excluded; in the
  lead-in only: used, with a note (the fit never sees it; detrend and the fit's offset
  and ramp absorb its effect on the trend);
* with two repeats the neighbouring levels decide which one differs; if they cannot, both
  are kept and the level is flagged; with one repeat only the single-trial checks apply;
* a level left with fewer usable repeats than ``min_repeats`` is kept and flagged.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

import numpy as np
from scipy.signal import sosfiltfilt

from nmsid.analysis.fatigue import (
    FatigueResult,
    cumulative_stimulation_s,
    fit_fatigue,
    gains_between_repeats,
)
from nmsid.analysis.qc import checks
from nmsid.analysis.qc.repeats import (
    Deviation,
    attribute_pair,
    deviations,
    fit_jump,
    smoothed,
    unshared,
)
from nmsid.analysis.qc.settings import QCSettings
from nmsid.protocols.reprs import html_repr, short_repr
from nmsid.protocols.session_file import Trial, read_session

USED, REPAIRED, EXCLUDED = "used", "repaired", "excluded"


@dataclass
class TrialQC:
    """The verdict on one trial.

    Attributes
    ----------
    trial : str
        Group name in the session file (``t001`` ...).
    sE, repeat : float, int
    decision : str
        ``used``, ``repaired``, ``excluded`` (``aborted`` for trials the rig aborted).
    reasons : list of str
        One sentence per finding (also for ``used`` trials: notes).
    spans : list of (float, float)
        Where, in s after stimulation onset.
    level_flag : str
        Set on every trial of a level left with too few usable repeats.
    """

    trial: str
    sE: float
    repeat: int
    decision: str
    reasons: list[str] = field(default_factory=list)
    spans: list[tuple[float, float]] = field(default_factory=list)
    level_flag: str = ""

    @property
    def kept(self) -> bool:
        return self.decision in (USED, REPAIRED)

    def to_dict(self) -> dict:
        """The ``qc.csv`` row (and ``nmsid qc --json``'s trial item)."""
        return {"trial": self.trial, "sE": self.sE, "repeat": self.repeat,
                "decision": self.decision, "reasons": "; ".join(self.reasons),
                "spans": " ".join(f"{a:.2f}-{b:.2f}" for a, b in self.spans),
                "level_flag": self.level_flag}


@dataclass(frozen=True)
class DecisionCounts:
    """How many judged trials each decision got (:meth:`SessionQC.counts`).

    Attributes
    ----------
    used, repaired, excluded : int
    """

    used: int = 0
    repaired: int = 0
    excluded: int = 0

    @property
    def total(self) -> int:
        """Every judged trial."""
        return self.used + self.repaired + self.excluded

    def to_dict(self) -> dict[str, int]:
        """``nmsid qc --json``'s ``counts``."""
        return {USED: self.used, REPAIRED: self.repaired, EXCLUDED: self.excluded}


@dataclass
class LevelQC:
    """The verdicts of one level and the trials identification should use."""

    sE: float
    verdicts: list[TrialQC]
    kept: list = field(default_factory=list)
    """Trials to average and fit (repaired data in place of the recorded force)."""
    flag: str = ""


@dataclass
class SessionQC:
    """The verdicts of a whole session."""

    participant: str
    source: str
    levels: list[LevelQC]
    fatigue: FatigueResult | None = None
    """Gain lost with accumulated stimulation, from each kept trial's gain against its
    level's other repeats (no model; :func:`nmsid.analysis.fatigue.gains_between_repeats`).
    A problem line of ``nmsid qc`` when significant."""

    @property
    def trials(self) -> list[TrialQC]:
        return [v for lv in self.levels for v in lv.verdicts]

    def __repr__(self) -> str:
        c = self.counts()
        return short_repr("SessionQC", self.participant,
                          f"{c.used} used, {c.repaired} repaired, {c.excluded} excluded",
                          f"{len(self.levels)} sE levels", str(self.source))

    _repr_html_ = html_repr

    def excluded(self) -> Mapping[str, str]:
        """Trial name -> reasons, for every excluded trial.

        Returns
        -------
        Mapping of str to str
            Read-only, in session order (what ``load_session(excluded=...)`` takes).
        """
        return MappingProxyType({v.trial: "; ".join(v.reasons) for v in self.trials
                                 if v.decision == EXCLUDED})

    def counts(self) -> DecisionCounts:
        """How many judged trials were used, repaired and excluded."""
        d = [v.decision for v in self.trials]
        return DecisionCounts(used=d.count(USED), repaired=d.count(REPAIRED),
                              excluded=d.count(EXCLUDED))


# -- one trial on its own ---------------------------------------------------------------
@dataclass
class _Work:
    trial: Trial
    verdict: TrialQC
    force: np.ndarray
    noise_sd: float = float("nan")
    bridged_s: float = 0.0
    smooth_cache: dict = dataclasses.field(default_factory=dict)
    batch: dict = dataclasses.field(default_factory=dict)
    """This trial's force as recorded (``force``) filtered with the other trials of its
    length in one call (:func:`_filter_together`): ``spike_lowpassed`` and ``smoothed``."""

    def smoothed(self, n: int, s: QCSettings) -> tuple[np.ndarray, float]:
        """The first ``n`` samples of the (possibly bridged) force, smoothed once."""
        key = (n, id(self.force))
        if key not in self.smooth_cache and n == self.force.size and \
                self.force is self.batch.get("force"):
            self.smooth_cache[key] = self.batch["smoothed"]   # filtered with the session
        if key not in self.smooth_cache:
            self.smooth_cache[key] = smoothed(self.force[:n], float(self.trial.fs_Hz), s)
        return self.smooth_cache[key]


def _window_start(trial) -> float:
    return float(trial.steady_s)


def _filter_together(trials, s: QCSettings) -> dict[int, dict]:
    """The two zero-phase filters every trial's force passes (the spike search's low-pass
    and the repeats' smoothing), run on all trials of one length and rate in one call
    each: ``id(trial)`` -> ``{"force", "spike_lowpassed", "smoothed"}``. Trials whose
    force is not finite (bridged first) are left out; the result is the same as filtering
    each trial on its own (rows are independent)."""
    groups: dict[tuple, list] = {}
    for tr in trials:
        f = np.asarray(tr.force_N, float)
        if f.ndim == 1 and f.size >= 0.5 * float(tr.fs_Hz) and np.isfinite(f).all():
            groups.setdefault((f.size, float(tr.fs_Hz)), []).append((tr, f))
    out: dict[int, dict] = {}
    for (n, fs), members in groups.items():
        fc = min(s.spike_highpass_Hz, 0.4 * fs)
        if len(members) < 2 or n < int(fs / fc) * 8:
            continue    # alone or too short: _single filters it as before
        F = np.vstack([f for _, f in members])
        low = sosfiltfilt(checks.spike_lowpass_sos(fs, s.spike_highpass_Hz), F)
        sm, fs_s = smoothed(F, fs, s)
        for k, (tr, f) in enumerate(members):
            out[id(tr)] = {"force": f, "spike_lowpassed": low[k], "smoothed": (sm[k], fs_s)}
    return out


def _single(trial, s: QCSettings, batch: dict | None = None) -> _Work:
    fs = float(trial.fs_Hz)
    v = TrialQC(trial.name, float(trial.sE), int(trial.repeat), USED)
    batch = batch or {}
    w = _Work(trial, v, batch["force"] if batch else np.asarray(trial.force_N, float),
              batch=batch)
    start_s = _window_start(trial)

    def exclude(reason, span=None):
        v.decision = EXCLUDED
        v.reasons.append(reason)
        if span:
            v.spans.append(span)

    def span_s(a, b):
        return (round(a / fs, 4), round(b / fs, 4))

    if not np.all(np.isfinite(trial.rE)):
        exclude("non-finite samples in the commanded rE record")
        return w
    if w.force.size < 0.5 * fs:
        v.reasons.append(f"only {w.force.size / fs:.2f} s recorded: too short to judge")
        return w
    to_bridge = []
    for f in checks.nonfinite(w.force, fs, s.nonfinite_max_s, "force_N"):
        a, b = f.spans[0]
        if f.repairable:
            to_bridge.append((a, b))
            v.reasons.append(f"{f.detail} bridged")
            v.spans.append(span_s(a, b))
        else:
            exclude(f"{f.detail} ({(b - a) / fs * 1000:.0f} ms, too long to bridge)",
                    span_s(a, b))
    if v.decision == EXCLUDED:
        return w
    if to_bridge:
        w.force = checks.bridge(w.force, to_bridge, margin=0)
        w.bridged_s += sum(b - a for a, b in to_bridge) / fs
    found = checks.spikes(w.force, fs, s.spike_highpass_Hz, s.spike_k, s.spike_max_s,
                          lowpassed=batch.get("spike_lowpassed") if w.force is batch.get("force")
                          else None)
    if found:
        spans = [f.spans[0] for f in found]
        w.bridged_s += sum(b - a + 2 for a, b in spans) / fs
        w.force = checks.bridge(w.force, spans, margin=1)
        v.reasons.append(f"{len(found)} spike(s) bridged (largest "
                         f"{max(float(f.detail.split()[2]) for f in found):.3g} N)")
        v.spans.extend(span_s(a, b) for a, b in spans[:5])
    if w.bridged_s > s.repair_max_total_s:
        exclude(f"{1000 * w.bridged_s:.0f} ms would need bridging (more than "
                f"{1000 * s.repair_max_total_s:.0f} ms)")
        return w
    dx = np.diff(w.force)            # shared by the noise, the resolution and the flat runs
    d2 = np.diff(dx)
    w.noise_sd = checks.noise_sd_of_second_difference(d2)   # checks.hf_noise_sd(w.force)
    for f in checks.flat_runs(w.force, fs, s.stall_min_s, s.clip_min_s, w.noise_sd, dx=dx):
        a, b = f.spans[0]
        if b / fs > start_s:
            exclude(f"{f.kind}: {f.detail}", span_s(a, b))
        else:
            v.reasons.append(f"{f.kind} in the lead-in only (not fitted): {f.detail}")
            v.spans.append(span_s(a, b))
    lead = range(w.force.size)[int(0.5 * fs):int(start_s * fs)]
    if len(lead) > 0.5 * fs:
        # checks.hf_noise_sd of the lead-in: its second difference is a slice of the trial's
        w.noise_sd = checks.noise_sd_of_second_difference(d2[lead.start:lead.stop - 2])
    if v.decision == USED and w.bridged_s > 0:
        v.decision = REPAIRED
    return w


# -- a level: its repeats against each other ---------------------------------------------
def _comparable(works: list[_Work], tol: float) -> tuple[list[_Work], int]:
    """The trials whose rE agree with the first's, and their common length."""
    if not works:
        return [], 0
    n = min(w.force.size for w in works)
    r0 = np.asarray(works[0].trial.rE[:n], float)
    same = [w for w in works if np.max(np.abs(np.asarray(w.trial.rE[:n], float) - r0)) <= tol]
    return same, n


def _compare(works: list[_Work], s: QCSettings, neighbour: np.ndarray | None) -> str:
    """Judge the repeats against each other; returns a level note ('' if none)."""
    live = [w for w in works if w.verdict.decision != EXCLUDED]
    same, n = _comparable(live, s.rE_match_tol)
    if len(live) >= 2 and len(same) < len(live):
        return "repeats received different rE; not compared with each other"
    if len(same) < 2:
        if len(live) == 1:
            live[0].verdict.reasons.append("single repeat: only the single-trial checks "
                                           "apply")
        return ""
    sig = []
    for w in same:
        y, fs_s = w.smoothed(n, s)
        sig.append(y)
    u, flags, rms, typical, response, refs, limit = unshared(sig, fs_s, s)
    devs = [deviations(u[i], flags[i], rms[i], fs_s, typical, s) for i in range(len(same))]
    for i, ds in enumerate(devs):
        # one jump may explain everything a trial does not share (a robust line cannot
        # follow a step over half a trial, so it shows as several stretches)
        if ds and ds[-1].stop_s >= sig[i].size / fs_s - 1.0:
            jump = fit_jump(sig[i], refs[i], fs_s, limit, s)
            if jump is not None:
                h, at = jump
                devs[i] = [Deviation(at, sig[i].size / fs_s, abs(h), abs(h) / typical
                                     if typical > 0 else float("inf"), h, at)]
    note = ""
    if len(same) == 2 and devs[0] and devs[1]:
        owners = []
        for d in devs[0]:
            owners.append(attribute_pair(sig, neighbour, fs_s, (d.start_s, d.stop_s), s))
        if any(o is None for o in owners):
            note = ("the two repeats differ at " + ", ".join(
                f"{d.start_s:.1f}-{d.stop_s:.1f} s" for d in devs[0]) +
                " and the neighbouring levels cannot tell which one is the response")
            for w in same:
                w.verdict.reasons.append(note)
            return note
        devs = [[d for d, o in zip(devs[0], owners, strict=True) if o == 0],
                [d for d, o in zip(devs[0], owners, strict=True) if o == 1]]
    for w, ds in zip(same, devs, strict=True):
        _apply(w, ds, typical, s)
    return note


def _apply(w: _Work, ds, typical: float, s: QCSettings) -> None:
    v = w.verdict
    fs = float(w.trial.fs_Hz)
    start_s = _window_start(w.trial)
    for d in ds:
        if d.stop_s <= s.onset_ignore_s:
            continue
        span = (round(d.start_s, 2), round(d.stop_s, 2))
        if d.is_jump:
            k = int(round(d.step_at_s * fs))
            w.force = w.force.copy()
            w.force[k:] -= d.step_N
            v.reasons.append(f"baseline jump of {d.step_N:+.3g} N at {d.step_at_s:.2f} s "
                             "removed")
            v.spans.append(span)
            if v.decision == USED:
                v.decision = REPAIRED
        elif d.stop_s > start_s:
            v.decision = EXCLUDED
            v.reasons.append(f"response not explained by rE at {span[0]:.2f}-{span[1]:.2f} s "
                             f"(RMS {d.rms_N:.3g} N, {d.ratio:.0f}x the repeats' typical "
                             "difference)")
            v.spans.append(span)
        else:
            v.reasons.append(f"response not explained by rE in the lead-in only "
                             f"({span[0]:.2f}-{span[1]:.2f} s, not fitted)")
            v.spans.append(span)


def _level_reference(works: list[_Work], s: QCSettings) -> np.ndarray | None:
    live = [w for w in works if w.verdict.decision != EXCLUDED]
    same, n = _comparable(live, s.rE_match_tol)
    if not same:
        return None
    sig = [w.smoothed(n, s)[0] for w in same]
    S = np.vstack(sig)
    return np.median(S - np.median(S, axis=1, keepdims=True), axis=0)


def _finish(sE: float, works: list[_Work], note: str, s: QCSettings) -> LevelQC:
    kept = []
    for w in works:
        if w.verdict.kept:
            tr = w.trial
            if w.verdict.decision == REPAIRED:
                tr = dataclasses.replace(tr, force_N=w.force)
            kept.append(tr)
    flag = note
    n_judged = len(works)
    if n_judged >= s.min_repeats and len(kept) < s.min_repeats:
        flag = (f"only {len(kept)} usable repeat(s) of {n_judged} at sE={sE:g}"
                + ("; parameters rest on a single trial" if len(kept) == 1 else
                   "; level not identified" if not kept else ""))
    if flag:
        for w in works:
            w.verdict.level_flag = flag
    return LevelQC(sE, [w.verdict for w in works], kept, flag)


def assess_level(trials, settings: QCSettings | None = None,
                 neighbour: np.ndarray | None = None) -> LevelQC:
    """Judge the completed repeats of one sE level.

    Parameters
    ----------
    trials : sequence of protocols.session_file.Trial
        The level's trials; aborted ones are ignored (identification reports them).
    settings : QCSettings, optional
    neighbour : array, optional
        The neighbouring levels' smoothed response (decides between two repeats).

    Returns
    -------
    LevelQC
        Verdicts, the trials to use (repaired data in place) and the level's flag.
    """
    s = settings or QCSettings()
    trials = [t for t in trials if t.completed]
    if not trials:
        return LevelQC(float("nan"), [], [], "")
    works = [_single(t, s) for t in trials]
    note = _compare(works, s, neighbour)
    return _finish(float(trials[0].sE), works, note, s)


def assess_session(session, settings: QCSettings | None = None) -> SessionQC:
    """Judge every completed trial of a session (path or read session).

    Lead-in noise is compared across the whole session; two-repeat levels are decided
    with the neighbouring levels; everything else as :func:`assess_level`.
    """
    s = settings or QCSettings()
    if isinstance(session, (str, os.PathLike)):
        session = read_session(session, datasets=("rE", "force_N"))
    groups: dict[float, list] = {}
    for tr in session.trials:
        if tr.completed:
            groups.setdefault(round(float(tr.sE), 9), []).append(tr)
    keys = sorted(groups)
    batch = _filter_together([t for k in keys for t in groups[k]], s)
    works = {k: [_single(t, s, batch.get(id(t))) for t in groups[k]] for k in keys}
    noise = np.array([w.noise_sd for k in keys for w in works[k]
                      if w.verdict.decision != EXCLUDED and np.isfinite(w.noise_sd)])
    if noise.size >= 3:
        typical = float(np.median(noise))
        for k in keys:
            for w in works[k]:
                if w.verdict.decision != EXCLUDED and typical > 0 and \
                        w.noise_sd > s.noise_ratio_max * typical:
                    w.verdict.decision = EXCLUDED
                    w.verdict.reasons.append(
                        f"lead-in noise {w.noise_sd:.3g} N is {w.noise_sd / typical:.1f}x "
                        f"the session's median {typical:.3g} N (loose electrode or cable, "
                        "or activity the stimulation did not cause)")
    refs: dict = {}

    def reference(k):          # computed only for a two-repeat level's neighbours
        if k not in refs:
            refs[k] = _level_reference(works[k], s)
        return refs[k]

    levels = []
    for i, k in enumerate(keys):
        neighbour = None
        if sum(w.verdict.decision != EXCLUDED for w in works[k]) == 2:
            around = [keys[j] for j in (i - 1, i + 1) if 0 <= j < len(keys)]
            near = [reference(j) for j in around if len(works[j]) >= 3]
            near = [x for x in near if x is not None]
            if not near:
                near = [reference(j) for j in around]
                near = [x for x in near if x is not None]
            if near:
                m = min(x.size for x in near)
                neighbour = np.mean([x[:m] for x in near], axis=0)
        note = _compare(works[k], s, neighbour)
        levels.append(_finish(float(groups[k][0].sE), works[k], note, s))
    return SessionQC(session.participant, str(session.path), levels,
                     fatigue=_session_fatigue(session.trials, levels))


def _session_fatigue(all_trials, levels: list[LevelQC]) -> FatigueResult | None:
    """Fatigue from the trials QC keeps (see :class:`SessionQC`)."""
    centre, total = cumulative_stimulation_s(all_trials)
    cum = {id(t): float(c) for t, c in zip(all_trials, centre, strict=True)}
    kept = [t for lv in levels for t in lv.kept]
    # a repaired trial is a copy with its bridged force: find its place by name
    by_name = {t.name: cum[id(t)] for t in all_trials if t.name}
    c = [cum.get(id(t), by_name.get(t.name, float("nan"))) for t in kept]
    if len(kept) < 3:
        return None
    g = gains_between_repeats(kept)
    return fit_fatigue(g, [round(float(t.sE), 9) for t in kept], c, total_stim_s=total,
                       source="each kept repeat against its level's mean")
