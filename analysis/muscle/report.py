"""What the gap report says about the muscle twin: ``gap_report.json``'s ``muscle_twin``
section, the twin file's ``muscle_model`` item and the figure ``muscle.png`` (where the
muscle twin helps: by sE, by chirp band, by ``|rE - 0.5|``)."""

from __future__ import annotations

from itertools import pairwise
from pathlib import Path

import numpy as np

from nmsid.analysis import plot_style as style
from nmsid.analysis.muscle.twin_form import muscle_entry

#: Bins of the commanded deviation's size |rE - 0.5|.
ABS_DEVIATION_EDGES = (0.0, 0.1, 0.2, 0.3, 0.4, 0.5)


def _nrmse(r, ref):
    den = float(np.sum(ref ** 2))
    return 100.0 * float(np.sqrt(np.sum(r ** 2) / den)) if den > 0 else float("nan")


def _where(diag, resid) -> dict:
    d = diag.data
    ok = diag.tested
    ref = diag.reference
    out: dict[str, list[dict]] = {"sE": [], "band": [], "abs_deviation": []}
    for j, sE in enumerate(d.sE_levels):
        rows = np.flatnonzero(ok & (d.level == j))
        if len(rows):
            out["sE"].append({"sE": float(sE), "nrmse_pct": _nrmse(resid[rows], ref[rows])})
    edges = diag.settings.bands_Hz
    f = d.f_inst_Hz
    for lo, hi in pairwise(edges):
        m = (f >= lo) & (f <= hi)
        if np.any(m):
            out["band"].append({"f_lo_Hz": lo, "f_hi_Hz": hi,
                                "nrmse_pct": _nrmse(resid[ok][:, m], ref[ok][:, m])})
    dev = np.abs(d.d_eval)
    e = ABS_DEVIATION_EDGES
    for lo, hi in pairwise(e):
        m = ok[:, None] & (dev >= lo) & (dev <= hi if hi == e[-1] else dev < hi)
        if np.any(m):
            out["abs_deviation"].append({"d_lo": lo, "d_hi": hi,
                                         "nrmse_pct": _nrmse(resid[m], ref[m])})
    return out


def muscle_section(diag) -> dict | None:
    """``gap_report.json``'s ``muscle_twin`` (None when it was not tried: the template's
    answer left no significant gap)."""
    m = diag.muscle_tried
    if m is None:
        return None
    final = diag.best_pair or diag.best
    tmpl = final if final is not None else diag.nominal
    floor = diag.noise_floor_nrmse_pct
    if not getattr(m, "converged", True):
        # a row that says so: the template's figures, nothing of the muscle twin's
        return {"supported": False, "converged": False, "note": m.note,
                "heldout": {"nominal_nrmse_pct": diag.nominal.heldout_nrmse_pct,
                            "template": tmpl.label,
                            "template_nrmse_pct": tmpl.heldout_nrmse_pct,
                            "muscle_nrmse_pct": None, "noise_floor_nrmse_pct": floor,
                            "sensor_floor_nrmse_pct": diag.sensor_floor_nrmse_pct,
                            "muscle_to_noise_floor": None},
                "parameters": [], "not_determined": [], "fit_s": m.fit_s,
                "remainder": {"sentence": f"the muscle twin was not scored: {m.note}"}}
    where_m = _where(diag, m.heldout_resid)
    return {
        "supported": bool(m.supported), "converged": True, "note": "",
        "with_fatigue": bool(getattr(m, "with_fatigue", False)),
        "heldout": {"nominal_nrmse_pct": diag.nominal.heldout_nrmse_pct,
                    "template": tmpl.label, "template_nrmse_pct": tmpl.heldout_nrmse_pct,
                    "muscle_nrmse_pct": m.heldout_nrmse_pct,
                    "noise_floor_nrmse_pct": floor,
                    "sensor_floor_nrmse_pct": diag.sensor_floor_nrmse_pct,
                    "muscle_to_noise_floor": m.heldout_nrmse_pct / floor if floor > 0
                    else None},
        "insample_nrmse_pct": m.insample_nrmse_pct,
        "delta_ic": m.delta_ic, "delta_k": m.delta_k,
        "shrink_pct": m.shrink_pct, "shrink_vs_template_pct": m.shrink_vs_template_pct,
        "parameters": m.full.table(),
        "not_determined": [r["name"] for r in m.full.table() if not r["determined"]],
        "singular_values": [float(v) for v in m.full.singular_values],
        "fit_s": m.fit_s,
        "where": {"muscle": where_m, "template": _where(diag, tmpl.heldout_resid)},
        "remainder": _remainder_section(m.heldout_nrmse_pct, floor, where_m),
    }


def _remainder_section(muscle_pct: float, floor_pct: float, where: dict) -> dict:
    """How much the muscle twin leaves beyond the noise floor and where most of it lies
    (the sE level and the chirp band with the highest held-out NRMSE), with a sentence.

    Examples
    --------
    >>> w = {"sE": [{"sE": 0.3, "nrmse_pct": 3.0}, {"sE": 1.0, "nrmse_pct": 1.0}],
    ...      "band": [{"f_lo_Hz": 1, "f_hi_Hz": 4, "nrmse_pct": 0.5},
    ...               {"f_lo_Hz": 4, "f_hi_Hz": 10, "nrmse_pct": 2.5}]}
    >>> print(_remainder_section(1.2, 0.1, w)["sentence"])  # doctest: +NORMALIZE_WHITESPACE
    the muscle twin leaves 1.20 % held-out, 12.0x the noise floor (0.10 %); most at sE 0.3
    (3.00 %) and in the 4-10 Hz band (2.50 %)
    """
    ratio = muscle_pct / floor_pct if floor_pct > 0 else float("nan")
    worst_s = max(where.get("sE", []), key=lambda r: r["nrmse_pct"], default=None)
    worst_b = max(where.get("band", []), key=lambda r: r["nrmse_pct"], default=None)
    parts = []
    if worst_s is not None:
        parts.append(f"at sE {worst_s['sE']:g} ({worst_s['nrmse_pct']:.2f} %)")
    if worst_b is not None:
        parts.append(f"in the {worst_b['f_lo_Hz']:g}-{worst_b['f_hi_Hz']:g} Hz band "
                     f"({worst_b['nrmse_pct']:.2f} %)")
    sentence = (f"the muscle twin leaves {muscle_pct:.2f} % held-out, {ratio:.1f}x the noise "
                f"floor ({floor_pct:.2f} %)" + ("; most " + " and ".join(parts) if parts
                                                else ""))
    return {"heldout_nrmse_pct": muscle_pct, "to_noise_floor": ratio,
            "worst_sE": worst_s, "worst_band": worst_b, "sentence": sentence}


def twin_item(diag) -> dict | None:
    """The twin file's ``muscle_model`` when the muscle twin won, else None."""
    if diag.muscle is None:
        return None
    return muscle_entry(diag.muscle.full, diag.settings.muscle_fs_Hz)


def plot_muscle(section: dict, path: Path) -> None:
    """Held-out NRMSE of the template's answer and of the muscle twin by sE, by chirp band
    and by |rE - 0.5|, with the noise floor; a value the fit did not give (None or NaN:
    not converged) is left out and named."""
    plt = style.pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.8))
    w = section["where"]
    floor = section["heldout"].get("noise_floor_nrmse_pct")
    specs = [("sE", lambda r: f"{r['sE']:g}", r"stimulation level $s_E$"),
             ("band", lambda r: f"{r['f_lo_Hz']:g}-{r['f_hi_Hz']:g}",
              "chirp frequency band (Hz)"),
             ("abs_deviation", lambda r: f"{r['d_lo']:g}-{r['d_hi']:g}",
              r"commanded deviation $|r_E - 0.5|$")]
    for ax, (key, lab, xlabel) in zip(axes, specs, strict=True):
        rows_t, rows_m = w["template"].get(key, []), w["muscle"].get(key, [])
        t = style.finite([r.get("nrmse_pct") for r in rows_t])
        m = style.finite([r.get("nrmse_pct") for r in rows_m])
        x = np.arange(len(rows_t))
        template = style.effect_title(str(section["heldout"].get("template")))
        ax.bar(x - 0.2, t, 0.4, color=style.COLOURS["reference"],
               label=f"template ({template})")
        ax.bar(np.arange(len(m)) + 0.2, m, 0.4, color=style.COLOURS["winner"],
               label="muscle twin")
        style.mark_missing(ax, x - 0.2, t)
        style.mark_missing(ax, np.arange(len(m)) + 0.2, m)
        if floor is not None and np.isfinite(floor):
            ax.axhline(floor, ls=":", color=style.COLOURS["noise"], label="noise floor")
        ax.set_xticks(x)
        ax.set_xticklabels([lab(r) for r in rows_t], rotation=45, ha="right")
        ax.set_xlabel(xlabel)
        ax.set_ylabel("held-out NRMSE (%)")
    style.legend_outside(axes[-1], "right")
    fig.suptitle("where the muscle twin helps: template against muscle twin")
    fig.tight_layout()
    style.save(fig, path)
