"""``nmsid control report``: tracking error per trial and per controller.

Per tracking trial (``trial_kind = "tracking"``): the RMSE of force - target after the
lead-in in % of the target's range; for step targets the overshoot past each new level (%
of the step) and the settling time into +-5 % of the step (s, ``nan`` when a level is never
settled into: said in the report); the largest error. Per controller: the mean over its
completed trials and per target. ``tracking.json`` holds them, ``report.md`` says them,
``figures/`` shows target and achieved force per target, both controllers.

Honest answers: aborted trials are listed with their samples and left out of the means;
a controller without a completed trial has ``null`` figures and the report says why.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from nmsid.analysis import plot_style as style
from nmsid.analysis.control.design import rmse_pct_of_range
from nmsid.analysis.control.errors import TrackingReportError
from nmsid.analysis.control.targets import Target
from nmsid.protocols.joints import recorded_quantity

SETTLE_BAND = 0.05
"""Settling: within this fraction of the step size."""


@dataclass
class TrialMetrics:
    """One tracking trial's figures."""

    trial: str
    controller: str
    target: str
    status: str
    n_samples: int
    rmse_pct_of_range: float | None
    max_error_N: float | None
    overshoot_pct: float | None = None
    settling_time_s: float | None = None
    latency_median_s: float | None = None
    unsettled_steps: int = 0
    """Steps never settled into within their hold (left out of the settling time)."""
    abort_reason: str = ""


@dataclass
class TrackingReport:
    """What ``tracking.json`` holds."""

    session: str
    trials: list[TrialMetrics] = field(default_factory=list)
    controllers: dict = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    measured_unit: str = "N"
    """The session's unit (``N``; ``N m`` at a knee or an ankle): of ``max_error_N``."""

    def to_dict(self) -> dict:
        return {"session": self.session, "controllers": self.controllers,
                "trials": [asdict(t) for t in self.trials], "notes": self.notes}


def _num(x) -> float | None:
    return None if x is None or not math.isfinite(float(x)) else round(float(x), 6)


def step_metrics(force_N: np.ndarray, target: Target, fs_Hz: float
                 ) -> tuple[float | None, float | None, int]:
    """(mean overshoot % of the step, mean settling time s of the steps settled into,
    number of steps never settled into within their hold) over a step target's steps."""
    levels = target.params["levels_N"]
    hold = float(target.params["hold_s"])
    over, settle = [], []
    for k in range(1, len(levels)):
        prev, new = float(levels[k - 1]), float(levels[k])
        step = new - prev
        if abs(step) < 1e-12:
            continue
        a = round((target.lead_s + k * hold) * fs_Hz)
        b = min(round((target.lead_s + (k + 1) * hold) * fs_Hz), len(force_N))
        if b - a < 2:
            continue
        seg = (np.asarray(force_N[a:b]) - prev) / step      # 0 -> 1 normalised
        over.append(max(0.0, float(seg.max()) - 1.0) * 100.0)
        outside = np.flatnonzero(np.abs(seg - 1.0) > SETTLE_BAND)
        if outside.size == 0:
            settle.append(0.0)
        elif outside[-1] == seg.size - 1:
            settle.append(math.nan)          # never settled within the hold
        else:
            settle.append((outside[-1] + 1) / fs_Hz)
    if not over:
        return None, None, 0
    ok = [x for x in settle if not math.isnan(x)]
    return (float(np.mean(over)), float(np.mean(ok)) if ok else None,
            len(settle) - len(ok))


def trial_metrics(trial) -> TrialMetrics:
    a = trial.extra_attrs
    target = Target.from_json(a["target_json"])
    stream = json.loads(a.get("stream_json") or "{}")
    tm = TrialMetrics(trial.name, str(a.get("controller", "")), target.name, trial.status,
                      trial.n_samples, None, None,
                      latency_median_s=_num(stream.get("latency_median_s")),
                      abort_reason=trial.abort_reason)
    if not trial.completed or trial.n_samples == 0:
        return tm
    r = target.force_at(np.arange(trial.n_samples) / trial.fs_Hz)
    skip = round(target.lead_s * trial.fs_Hz)
    tm.rmse_pct_of_range = _num(rmse_pct_of_range(trial.force_N, r, skip))
    tm.max_error_N = _num(np.max(np.abs(trial.force_N[skip:] - r[skip:])))
    if target.kind == "step":
        ov, st, unsettled = step_metrics(trial.force_N, target, trial.fs_Hz)
        tm.overshoot_pct, tm.settling_time_s = _num(ov), _num(st)
        tm.unsettled_steps = unsettled
    return tm


def tracking_report(session) -> TrackingReport:
    """Figures of a tracking session (a :class:`~nmsid.protocols.session_file.Session`).

    Raises
    ------
    TrackingReportError
        If it holds no tracking trials.
    """
    trials = [t for t in session.trials if t.extra_attrs.get("trial_kind") == "tracking"]
    if not trials:
        raise TrackingReportError(f"{session.path}: no tracking trials (a session of "
                                  "nmsid run --track)")
    rep = TrackingReport(session=Path(session.path).name,
                         measured_unit=recorded_quantity(session.attrs)[2])
    rep.trials = [trial_metrics(t) for t in trials]
    for name in sorted({m.controller for m in rep.trials}):
        mine = [m for m in rep.trials if m.controller == name]
        done = [m for m in mine if m.rmse_pct_of_range is not None]
        per_target: dict[str, list[float]] = {}
        for m in done:
            per_target.setdefault(m.target, []).append(float(m.rmse_pct_of_range or 0.0))
        st = [m.settling_time_s for m in done if m.settling_time_s is not None]
        ov = [m.overshoot_pct for m in done if m.overshoot_pct is not None]
        rep.controllers[name] = {
            "rmse_pct_of_range": _num(np.mean([m.rmse_pct_of_range for m in done]))
            if done else None,
            "per_target_rmse_pct": {k: _num(np.mean(v)) for k, v in per_target.items()},
            "overshoot_pct": _num(np.mean(ov)) if ov else None,
            "settling_time_s": _num(np.mean(st)) if st else None,
            "n_completed": len(done), "n_aborted": len(mine) - len(done)}
        if len(done) < len(mine):
            lost = sum(m.n_samples for m in mine if m.rmse_pct_of_range is None)
            rep.notes.append(f"{name}: {len(mine) - len(done)} aborted trial(s) "
                             f"({lost} samples) left out of its figures")
        if not done:
            rep.notes.append(f"{name}: no completed trial, no figures")
        unsettled = sum(m.unsettled_steps for m in done)
        if unsettled:
            rep.notes.append(f"{name}: {unsettled} step(s) never settled into within "
                             f"+-{SETTLE_BAND:.0%} of the step during their hold (left out "
                             "of the settling time)")
    t, b = (rep.controllers.get(k, {}).get("rmse_pct_of_range") for k in ("twin", "baseline"))
    if t is not None and b:
        rep.controllers["twin_over_baseline"] = _num(t / b)
    return rep


def report_markdown(rep: TrackingReport) -> str:
    lines = [f"# Tracking report: {rep.session}", "",
             "| controller | RMSE % of range | overshoot % | settling s | completed | aborted |",
             "|---|---|---|---|---|---|"]
    for name, c in rep.controllers.items():
        if not isinstance(c, dict):
            continue
        def f(x, spec=".2f"):
            return "-" if x is None else format(x, spec)
        lines.append(f"| {name} | {f(c['rmse_pct_of_range'])} | {f(c['overshoot_pct'], '.1f')}"
                     f" | {f(c['settling_time_s'], '.3f')} | {c['n_completed']} | "
                     f"{c['n_aborted']} |")
    if "twin_over_baseline" in rep.controllers:
        lines += ["", f"Twin / baseline RMSE: {rep.controllers['twin_over_baseline']:.3f}"]
    lines += ["", (f"| trial | controller | target | status | RMSE % | max error "
              f"{rep.measured_unit} | overshoot % "
              "| settling s | latency ms |"), "|---|---|---|---|---|---|---|---|---|"]
    for m in rep.trials:
        def g(x, spec=".2f", scale=1.0):
            return "-" if x is None else format(x * scale, spec)
        lines.append(f"| {m.trial} | {m.controller} | {m.target} | {m.status} | "
                     f"{g(m.rmse_pct_of_range)} | {g(m.max_error_N, '.3f')} | "
                     f"{g(m.overshoot_pct, '.1f')} | {g(m.settling_time_s, '.3f')} | "
                     f"{g(m.latency_median_s, '.2f', 1000.0)} |")
    if rep.notes:
        lines += ["", "Notes:", *[f"- {n}" for n in rep.notes]]
    return "\n".join(lines) + "\n"


def write_figures(session, out_dir: Path) -> list[str]:
    """One figure per target (PNG and PDF): the target and each controller's achieved
    force, and the tracking error (force - target) in its own panel beneath. Returns the
    PNG names ([] and nothing written without matplotlib)."""
    try:
        plt = style.pyplot()
    except ImportError:
        return []
    by_target: dict[str, list] = {}
    for t in session.trials:
        if t.extra_attrs.get("trial_kind") == "tracking" and t.n_samples:
            by_target.setdefault(Target.from_json(t.extra_attrs["target_json"]).name,
                                 []).append(t)
    out_dir.mkdir(exist_ok=True)
    names = []
    for name, trials in by_target.items():
        fig, (ax, ax_e) = plt.subplots(2, 1, figsize=(9, 4.6), sharex=True,
                                       gridspec_kw={"height_ratios": [2.4, 1.0]})
        tg = Target.from_json(trials[0].extra_attrs["target_json"])
        n = max(t.n_samples for t in trials)
        ts = np.arange(n) / trials[0].fs_Hz
        ax.plot(ts, tg.force_at(ts), "--", color="k", lw=1.4, label="target", zorder=3)
        for t in trials:
            line, = ax.plot(t.t_s, t.force_N, lw=0.7, alpha=0.85,
                            label=f"{t.extra_attrs.get('controller')} ({t.name}, {t.status})")
            ax_e.plot(t.t_s, np.asarray(t.force_N) - tg.force_at(np.asarray(t.t_s)), lw=0.6,
                      alpha=0.85,
                      color=line.get_color())
        ax_e.axhline(0.0, color="k", lw=0.5)
        ax_e.set_xlabel("time from onset (s)")
        quantity, unit = recorded_quantity(session.attrs)[1:]
        ax.set_ylabel(f"{quantity} ({unit})")
        ax_e.set_ylabel(f"error ({unit})\n{quantity} - target")
        who = session.participant or "unknown participant"
        ax.set_title(f"participant {who}: tracking the target {name!r}")
        style.legend_outside(ax, "right")
        fig.tight_layout()
        safe = "".join(c if c.isalnum() or c in "-_." else "_" for c in name)
        fname = f"tracking-{safe}.png"
        style.save(fig, out_dir / fname)
        names.append(fname)
    return names


def write_report(session, out_dir) -> TrackingReport:
    """``tracking.json``, ``report.md`` and ``figures/`` into ``out_dir`` (which exists)."""
    out = Path(out_dir)
    rep = tracking_report(session)
    figs = write_figures(session, out / "figures")
    if not figs:
        rep.notes.append("no figures: matplotlib (the 'plot' extra) is not installed")
    (out / "tracking.json").write_text(json.dumps(rep.to_dict(), indent=1, allow_nan=False)
                                       + "\n", encoding="utf-8")
    (out / "report.md").write_text(report_markdown(rep), encoding="utf-8")
    return rep
