"""Figures of the gap report (matplotlib, Agg backend: no display needed)."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def _plt():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def _bars(ax, labels, nominal, augmented, ylabel):
    x = np.arange(len(labels))
    w = 0.4
    ax.bar(x - w / 2, nominal, w, label="nominal", color="0.6")
    if augmented is not None:
        ax.bar(x + w / 2, augmented, w, label="augmented", color="tab:blue")
    ax.set_xticks(x)
    ax.set_xticklabels(labels, rotation=45, ha="right", fontsize=8)
    ax.set_ylabel(ylabel)
    ax.legend(fontsize=8)


def plot_where(loc: dict, path: Path, noise_floor_pct: float) -> None:
    """Held-out NRMSE by sE, by chirp band, by deviation and by trial position."""
    plt = _plt()
    nom, aug = loc["nominal"], loc.get("augmented")
    fig, axes = plt.subplots(2, 2, figsize=(11, 7.5))
    ax = axes[0, 0]
    _bars(ax, [f"{r['sE']:.2f}" for r in nom["sE"]], [r["nrmse_pct"] for r in nom["sE"]],
          [r["nrmse_pct"] for r in aug["sE"]] if aug else None, "held-out NRMSE (%)")
    ax.axhline(noise_floor_pct, color="k", ls=":", lw=1, label="noise floor")
    ax.set_title("by sE")
    ax = axes[0, 1]
    _bars(ax, [f"{r['f_lo_Hz']:g}-{r['f_hi_Hz']:g} Hz" for r in nom["band"]],
          [r["nrmse_pct"] for r in nom["band"]],
          [r["nrmse_pct"] for r in aug["band"]] if aug else None, "held-out NRMSE (%)")
    ax.set_title("by chirp frequency band")
    ax = axes[1, 0]
    _bars(ax, [f"{r['d_lo']:+.2f}..{r['d_hi']:+.2f}" for r in nom["deviation"]],
          [r["nrmse_pct"] for r in nom["deviation"]],
          [r["nrmse_pct"] for r in aug["deviation"]] if aug else None, "held-out NRMSE (%)")
    ax.set_title("by commanded deviation rE - 0.5")
    ax = axes[1, 1]
    c = [r["cum_stim_s"] for r in nom["position"]]
    ax.plot(c, [r["nrmse_pct"] for r in nom["position"]], "o", color="0.5", label="nominal")
    if aug:
        ax.plot([r["cum_stim_s"] for r in aug["position"]],
                [r["nrmse_pct"] for r in aug["position"]], "o", color="tab:blue", ms=4,
                label="augmented")
    ax.set_xlabel("cumulative stimulation at trial (s)")
    ax.set_ylabel("held-out NRMSE (%)")
    ax.set_title("by position in the session")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def plot_frequency(loc: dict, path: Path) -> None:
    """Transfer-function error (gain, phase) with coherence, and residual harmonics."""
    plt = _plt()
    fr = loc["frequency"]
    fig, axes = plt.subplots(3, 1, figsize=(8, 9), sharex=True)
    labels = {"nominal": "nominal (held out)", "augmented": "augmented (held out)",
              "footprint": "effect footprint: measured / augmented fit without the effect"}
    for key, color in (("nominal", "0.4"), ("augmented", "tab:blue"),
                       ("footprint", "tab:orange")):
        if key not in fr:
            continue
        v = fr[key]
        axes[0].semilogx(v["f_Hz"], v["gain_error_dB"], "o-", color=color, label=labels[key])
        axes[1].semilogx(v["f_Hz"], v["phase_error_deg"], "o-", color=color,
                         label=labels[key])
    axes[0].set_ylabel("gain error (dB)\nmeasured / simulated")
    axes[1].set_ylabel("phase error (deg)")
    ax2 = axes[0].twinx()
    ax2.semilogx(fr["nominal"]["f_Hz"], fr["nominal"]["coherence"], ":", color="tab:green")
    ax2.set_ylabel("coherence", color="tab:green")
    ax2.set_ylim(0, 1.05)
    for ax in axes[:2]:
        ax.axhline(0, color="k", lw=0.5)
        ax.legend(fontsize=8)
    v = fr["nominal"]["residual_harmonic_pct"]
    for k, style in (("1.5f", ":"), ("2f", "-"), ("3f", "-")):
        axes[2].semilogx(fr["nominal"]["f_Hz"], v[k], style, marker="o", ms=3,
                         label=f"nominal residual at {k}" + (" (noise ref.)" if k == "1.5f"
                                                            else ""))
    if "augmented" in fr:
        axes[2].semilogx(fr["augmented"]["f_Hz"], fr["augmented"]["residual_harmonic_pct"]["3f"],
                         "--", color="tab:blue", label="augmented residual at 3f")
    axes[2].set_ylabel("% of measured fundamental")
    axes[2].set_xlabel("instantaneous chirp frequency (Hz)")
    axes[2].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def plot_spectrum_and_gain(loc: dict, path: Path, f0_Hz: float) -> None:
    """Residual power spectrum (drift shows below the chirp band) and trial gain vs
    cumulative stimulation (fatigue shows as a falling trend)."""
    plt = _plt()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for key, color in (("nominal", "0.4"), ("augmented", "tab:blue")):
        if key in loc["spectrum"]:
            s = loc["spectrum"][key]
            f = np.asarray(s["f_Hz"])
            m = f > 0
            axes[0].loglog(f[m], np.asarray(s["power"])[m], color=color, label=key)
    axes[0].axvspan(f0_Hz, 10.0, color="0.9", label="chirp band")
    axes[0].set_xlabel("frequency (Hz)")
    axes[0].set_ylabel("held-out residual power (a.u.)")
    axes[0].legend(fontsize=8)
    g = loc["gain_vs_stimulation"]
    axes[1].plot(g["cum_stim_s"], g["gain_ratio"], "o")
    axes[1].axhline(1, color="k", lw=0.5)
    axes[1].set_xlabel("cumulative stimulation at trial (s)")
    axes[1].set_ylabel("trial gain, measured / nominal simulation")
    axes[1].set_title(f"slope {g['slope_per_100s']:+.4f} per 100 s")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def plot_ranking(ranking: list[dict], nominal_pct: float, noise_pct: float, path: Path
                 ) -> None:
    """Held-out NRMSE of every candidate against the nominal model and the noise floor."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(8, 0.45 * len(ranking) + 1.5))
    labels = [r["effect"] for r in ranking]
    vals = [r["heldout_nrmse_pct"] for r in ranking]
    colors = ["tab:blue" if r["supported"] else "0.7" for r in ranking]
    y = np.arange(len(labels))[::-1]
    ax.barh(y, vals, color=colors)
    ax.set_yticks(y)
    ax.set_yticklabels(labels, fontsize=8)
    ax.axvline(nominal_pct, color="tab:red", label="nominal")
    ax.axvline(noise_pct, color="k", ls=":", label="noise floor")
    ax.set_xlabel("held-out NRMSE (%) (blue: supported)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def plot_example(t_s, measured, nominal, augmented, title: str, path: Path) -> None:
    """One held-out trial: measured force against the nominal and augmented predictions."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(11, 3.5))
    ax.plot(t_s, measured, color="k", lw=1, label="measured (held out)")
    ax.plot(t_s, nominal, color="tab:red", lw=1, label="nominal twin")
    if augmented is not None:
        ax.plot(t_s, augmented, "--", color="tab:blue", lw=1, label="augmented twin")
    ax.set_xlabel("time since chirp start (s)")
    ax.set_ylabel("force (N), offset and trend removed")
    ax.set_title(title)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def plot_remaining(report: dict, path: Path) -> None:
    """The remaining gap: held-out residual power over the trial's own noise power (1 = as
    good as the noise allows) by sE, by chirp band and by session third, with the verdict."""
    plt = _plt()
    rem = report["remaining"]
    w = rem["where"]
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8), gridspec_kw={"width_ratios": [3, 2, 1]})
    panels = (
        ([f"{r['sE']:.2f}" for r in w["sE"]], [r["ratio_to_noise"] for r in w["sE"]], "by sE"),
        ([f"{r['f_lo_Hz']:g}-{r['f_hi_Hz']:g}" for r in w["chirp_band"]],
         [r["ratio_to_noise"] for r in w["chirp_band"]], "by chirp band (Hz)"),
        (["first", "middle", "last"],
         [v if v is not None else np.nan
          for v in w["trial_position"].get("ratio_to_noise_by_third", [])],
         "by session third"))
    for ax, (labels, vals, title) in zip(axes, panels):
        ax.bar(np.arange(len(vals)), vals, color="tab:orange" if rem["significant"] else "0.6")
        ax.axhline(1.0, color="k", ls=":", lw=1)
        ax.set_yscale("log")
        ax.set_xticks(np.arange(len(vals)))
        ax.set_xticklabels(labels, rotation=45, ha="right", fontsize=8)
        ax.set_title(title, fontsize=9)
    axes[0].set_ylabel("residual power / noise power")
    label = report.get("best_pair") and "+".join(report["best_pair"]) or report["best_effect"]
    fig.suptitle(f"verdict: {report['verdict']} ({label}); remaining beyond noise "
                 f"{rem['beyond_noise_pct_typical'] or 0:.2f} % of the response, "
                 + ("significant" if rem["significant"] else "not significant"), fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
