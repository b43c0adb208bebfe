"""Figures of the gap report (matplotlib through :mod:`nmsid.analysis.plot_style`: PNG and
PDF, legends outside the axes, a missing value drawn as a gap and named)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from nmsid.analysis import plot_style as style

_NRMSE = "held-out NRMSE (%)"


def _bars(ax, labels, nominal, augmented, ylabel, augmented_label="augmented"):
    x = np.arange(len(labels))
    w = 0.4
    nom = style.finite(nominal)
    ax.bar(x - w / 2, nom, w, label="nominal", color=style.COLOURS["reference"])
    if augmented is not None:
        aug = style.finite(augmented)
        ax.bar(x + w / 2, aug, w, label=augmented_label, color=style.COLOURS["augmented"])
        style.mark_missing(ax, x + w / 2, aug, "n/a")
    style.mark_missing(ax, x - w / 2, nom, "n/a")
    ax.set_xticks(x)
    ax.set_xticklabels(labels, rotation=45, ha="right")
    ax.set_ylabel(ylabel)


def _augmented_label(loc: dict) -> str:
    effect = loc.get("augmented_effect")
    return f"augmented ({style.effect_title(effect)})" if effect else "augmented"


def plot_where(loc: dict, path: Path, noise_floor_pct: float) -> None:
    """Held-out NRMSE by sE, by chirp band, by deviation and by trial position."""
    plt = style.pyplot()
    nom, aug = loc["nominal"], loc.get("augmented")
    aug_label = _augmented_label(loc)
    fig, axes = plt.subplots(2, 2, figsize=(11, 7.5))
    ax = axes[0, 0]
    _bars(ax, [f"{r['sE']:.2f}" for r in nom["sE"]], [r["nrmse_pct"] for r in nom["sE"]],
          [r["nrmse_pct"] for r in aug["sE"]] if aug else None, _NRMSE, aug_label)
    ax.axhline(noise_floor_pct, color=style.COLOURS["noise"], ls=":", lw=1,
               label="noise floor")
    ax.set_xlabel(r"stimulation level $s_E$")
    ax.set_title("by sE")
    ax = axes[0, 1]
    _bars(ax, [f"{r['f_lo_Hz']:g}-{r['f_hi_Hz']:g}" for r in nom["band"]],
          [r["nrmse_pct"] for r in nom["band"]],
          [r["nrmse_pct"] for r in aug["band"]] if aug else None, _NRMSE, aug_label)
    ax.set_xlabel("chirp frequency band (Hz)")
    ax.set_title("by chirp frequency band")
    ax = axes[1, 0]
    _bars(ax, [f"{r['d_lo']:+.2f} to {r['d_hi']:+.2f}" for r in nom["deviation"]],
          [r["nrmse_pct"] for r in nom["deviation"]],
          [r["nrmse_pct"] for r in aug["deviation"]] if aug else None, _NRMSE, aug_label)
    ax.set_xlabel(r"commanded deviation $r_E - 0.5$")
    ax.set_title("by commanded deviation")
    ax = axes[1, 1]
    ax.plot(style.finite([r["cum_stim_s"] for r in nom["position"]]),
            style.finite([r["nrmse_pct"] for r in nom["position"]]), "o",
            color=style.COLOURS["reference"], label="nominal")
    if aug:
        ax.plot(style.finite([r["cum_stim_s"] for r in aug["position"]]),
                style.finite([r["nrmse_pct"] for r in aug["position"]]), "o",
                color=style.COLOURS["augmented"], ms=4, label=aug_label)
    ax.set_xlabel("cumulative stimulation at the trial (s)")
    ax.set_ylabel(_NRMSE)
    ax.set_title("by position in the session")
    fig.tight_layout()
    style.legend_above(fig, axes[0, 0], axes[1, 1])
    style.save(fig, path)


def plot_frequency(loc: dict, path: Path) -> None:
    """Transfer-function error (gain, phase) with coherence, and residual harmonics."""
    plt = style.pyplot()
    fr = loc["frequency"]
    fig, axes = plt.subplots(3, 1, figsize=(9, 9), sharex=True)
    labels = {"nominal": "nominal (held out)", "augmented": "augmented (held out)",
              "footprint": "effect footprint:\nmeasured / augmented fit\nwithout the effect"}
    for key, color in (("nominal", "0.4"), ("augmented", "tab:blue"),
                       ("footprint", "tab:orange")):
        if key not in fr:
            continue
        v = fr[key]
        f = style.finite(v["f_Hz"])
        axes[0].semilogx(f, style.finite(v["gain_error_dB"]), "o-", ms=3, color=color,
                         label=labels[key])
        axes[1].semilogx(f, style.finite(v["phase_error_deg"]), "o-", ms=3, color=color,
                         label=labels[key])
    axes[0].set_ylabel("gain error (dB)\nmeasured / simulated")
    axes[1].set_ylabel("phase error (deg)")
    ax2 = axes[0].twinx()
    ax2.semilogx(style.finite(fr["nominal"]["f_Hz"]),
                 style.finite(fr["nominal"]["coherence"]), ":", color="tab:green",
                 label="coherence (right axis)")
    ax2.set_ylabel("coherence (-)", color="tab:green")
    ax2.set_ylim(0, 1.05)
    ax2.grid(False)
    ax2.spines["right"].set_visible(True)
    for ax in axes[:2]:
        ax.axhline(0, color="k", lw=0.5)
    h1, l1 = axes[0].get_legend_handles_labels()
    h2, l2 = ax2.get_legend_handles_labels()
    axes[0].legend(h1 + h2, l1 + l2, loc="upper left", bbox_to_anchor=(1.08, 1.0))
    v = fr["nominal"]["residual_harmonic_pct"]
    f = style.finite(fr["nominal"]["f_Hz"])
    for k, ls in (("1.5f", ":"), ("2f", "-"), ("3f", "-")):
        axes[2].semilogx(f, style.finite(v[k]), ls, marker="o", ms=3,
                         label=f"nominal residual at {k}" + (" (noise ref.)" if k == "1.5f"
                                                            else ""))
    if "augmented" in fr:
        axes[2].semilogx(style.finite(fr["augmented"]["f_Hz"]),
                         style.finite(fr["augmented"]["residual_harmonic_pct"]["3f"]),
                         "--", color="tab:blue", label="augmented residual at 3f")
    axes[2].set_ylabel("% of the measured\nfundamental")
    axes[2].set_xlabel("instantaneous chirp frequency (Hz)")
    style.plain_log_ticks(axes[2])
    style.legend_outside(axes[2], "right")
    fig.tight_layout()
    style.save(fig, path)


def plot_spectrum_and_gain(loc: dict, path: Path, f0_Hz: float) -> None:
    """Residual power spectrum (drift shows below the chirp band) and trial gain vs
    cumulative stimulation (fatigue shows as a falling trend)."""
    plt = style.pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for key, color in (("nominal", "0.4"), ("augmented", "tab:blue")):
        if key in loc["spectrum"]:
            s = loc["spectrum"][key]
            f = style.finite(s["f_Hz"])
            m = f > 0
            axes[0].loglog(f[m], style.finite(s["power"])[m], color=color, label=key)
    axes[0].axvspan(f0_Hz, 10.0, color="0.9", label="chirp band")
    axes[0].set_xlabel("frequency (Hz)")
    style.plain_log_ticks(axes[0])
    axes[0].set_ylabel("held-out residual power (a.u.)")
    axes[0].set_title("residual spectrum")
    axes[0].legend(loc="lower left")
    g = loc["gain_vs_stimulation"]
    axes[1].plot(style.finite(g["cum_stim_s"]), style.finite(g["gain_ratio"]), "o",
                 color=style.COLOURS["measured"])
    axes[1].axhline(1, color="k", lw=0.5)
    axes[1].set_xlabel("cumulative stimulation at the trial (s)")
    axes[1].set_ylabel("trial gain, measured / nominal (-)")
    slope = g.get("slope_per_100s")
    axes[1].set_title("gain against stimulation: slope "
                      + ("n/a" if slope is None else f"{slope:+.4f} per 100 s"))
    fig.tight_layout()
    style.save(fig, path)


def winner_label(report: dict) -> str | None:
    """The ranking row (or ``"muscle twin"``) the verdict names, or None.

    Examples
    --------
    >>> winner_label({"verdict": "effect", "best_effect": "dead_time", "best_pair": None})
    'dead_time'
    >>> winner_label({"verdict": "pair", "best_pair": ["fatigue", "dead_time"]})
    'fatigue+dead_time'
    >>> winner_label({"verdict": "likely", "likely": {"label": "recruitment"}})
    'recruitment'
    >>> winner_label({"verdict": "none"}) is None
    True
    """
    verdict = report.get("verdict")
    if verdict == "muscle_twin":
        return "muscle twin"
    if verdict == "pair" and report.get("best_pair"):
        return "+".join(report["best_pair"])
    if verdict == "effect":
        return report.get("best_effect")
    if verdict == "likely":           # wins on evidence, not separable from scatter
        return (report.get("likely") or {}).get("label")
    return None


def plot_ranking(ranking: list[dict], nominal_pct: float, noise_pct: float, path: Path,
                 muscle: dict | None = None, winner: str | None = None) -> None:
    """Held-out NRMSE of every candidate, of the muscle twin when it was tried, against
    the nominal model and the noise floor; the verdict's winner in green and named."""
    plt = style.pyplot()
    rows = [(r["effect"], r.get("heldout_nrmse_pct"), bool(r.get("supported")))
            for r in ranking]
    if muscle is not None:
        rows.append(("muscle twin", muscle.get("heldout", {}).get("muscle_nrmse_pct"),
                     bool(muscle.get("supported"))))
    rows.sort(key=lambda r: np.inf if r[1] is None else r[1])
    fig, ax = plt.subplots(figsize=(8, 0.42 * len(rows) + 1.6))
    y = np.arange(len(rows))[::-1]
    vals = style.finite([r[1] for r in rows])
    winner_key = None if winner is None else set(winner.split("+"))
    colours, names = [], []
    for name, _, supported in rows:
        won = winner_key is not None and set(name.split("+")) == winner_key
        colours.append(style.COLOURS["winner"] if won
                       else style.COLOURS["augmented"] if supported
                       else style.COLOURS["unsupported"])
        names.append(style.effect_title(name) + ("  (verdict)" if won else ""))
    ax.barh(y, np.nan_to_num(vals, nan=0.0), color=colours)
    for yi, v in zip(y, vals, strict=True):
        ax.text(v if np.isfinite(v) else 0.0, yi, f" {v:.3g} %" if np.isfinite(v)
                else " not converged", va="center", fontsize=7.5)
    ax.set_yticks(y)
    ax.set_yticklabels(names)
    ax.axvline(nominal_pct, color="tab:red", label=f"nominal model ({nominal_pct:.3g} %)")
    ax.axvline(noise_pct, color="k", ls=":", label=f"noise floor ({noise_pct:.3g} %)")
    ax.bar([0], [0], color=style.COLOURS["winner"], label="the verdict's model")
    ax.bar([0], [0], color=style.COLOURS["augmented"], label="supported")
    ax.bar([0], [0], color=style.COLOURS["unsupported"], label="not supported")
    ax.set_xlabel(_NRMSE)
    ax.set_title("candidates ranked by held-out NRMSE")
    ax.grid(axis="y", visible=False)
    style.legend_outside(ax, "right")
    fig.tight_layout()
    style.save(fig, path)


def plot_example(t_s, measured, nominal, augmented, title: str, path: Path, *,
                 quantity: str = "force", unit: str = "N") -> None:
    """One held-out trial: the measured force (or torque, in ``unit``) under the nominal
    and augmented predictions, and their residuals in a panel beneath."""
    plt = style.pyplot()
    fig, (ax, ax_r) = plt.subplots(2, 1, figsize=(11, 4.8), sharex=True,
                                   gridspec_kw={"height_ratios": [2.4, 1.0]})
    ax.plot(t_s, measured, color=style.COLOURS["reference"], lw=2.2,
            label="measured (held out)")
    ax.plot(t_s, nominal, color="tab:red", lw=0.8, label="nominal twin")
    ax_r.plot(t_s, np.asarray(measured) - np.asarray(nominal), color="tab:red", lw=0.6,
              label="measured - nominal")
    if augmented is not None:
        ax.plot(t_s, augmented, "--", color="tab:blue", lw=0.9, label="augmented twin")
        ax_r.plot(t_s, np.asarray(measured) - np.asarray(augmented), color="tab:blue",
                  lw=0.6, label="measured - augmented")
    ax_r.axhline(0.0, color="k", lw=0.5)
    ax_r.set_xlabel("time since chirp start (s)")
    ax.set_ylabel(f"{quantity} ({unit}), offset\nand trend removed")
    ax_r.set_ylabel(f"residual ({unit})")
    ax.set_title(title)
    style.legend_outside(ax, "right")
    style.legend_outside(ax_r, "right")
    fig.tight_layout()
    style.save(fig, path)


def plot_remaining(report: dict, path: Path) -> None:
    """The remaining gap: held-out residual power over the trial's own noise power (1 = as
    good as the noise allows) by sE, by chirp band and by session third, with the verdict."""
    plt = style.pyplot()
    rem = report["remaining"]
    w = rem["where"]
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8), gridspec_kw={"width_ratios": [3, 2, 1]})
    panels = (
        ([f"{r['sE']:.2f}" for r in w["sE"]], [r["ratio_to_noise"] for r in w["sE"]],
         "by sE", r"stimulation level $s_E$"),
        ([f"{r['f_lo_Hz']:g}-{r['f_hi_Hz']:g}" for r in w["chirp_band"]],
         [r["ratio_to_noise"] for r in w["chirp_band"]], "by chirp band",
         "chirp frequency band (Hz)"),
        (["first", "middle", "last"],
         w["trial_position"].get("ratio_to_noise_by_third", []), "by session third",
         "part of the session"))
    for ax, (labels, raw, title, xlabel) in zip(axes, panels, strict=True):
        vals = style.finite(raw)
        x = np.arange(len(vals))
        ax.bar(x, vals, color="tab:orange" if rem["significant"] else "0.6")
        style.mark_missing(ax, x, vals, "n/a")
        ax.axhline(1.0, color="k", ls=":", lw=1)
        if np.any(np.isfinite(vals) & (vals > 0)):
            ax.set_yscale("log")
        ax.set_xticks(x)
        ax.set_xticklabels(labels[:len(vals)], rotation=45, ha="right")
        ax.set_title(title)
        ax.set_xlabel(xlabel)
    axes[0].set_ylabel("residual power / noise power (-)")
    label = style.effect_title(report.get("best_pair") and "+".join(report["best_pair"])
                               or report["best_effect"])
    fig.suptitle(f"verdict: {report['verdict']} ({label}); remaining beyond noise "
                 f"{rem['beyond_noise_pct_typical'] or 0:.2f} % of the response, "
                 + ("significant" if rem["significant"] else "not significant"))
    fig.tight_layout()
    style.save(fig, path)
