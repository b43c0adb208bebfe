"""The verdict: is there a gap beyond noise, does a candidate explain it, what remains, where.

Noise reference. Each trial's steady lead-in (rE = 0.5, no model involved) gives the power
of its measurement noise as the force is filtered (``GapData.steady_noise_N2``). A model's
held-out residual power in the window of trial ``i``, ``P_i``, is compared with that trial's
noise power ``N_i``: ``ratio_i = P_i / N_i`` is about 1 when the model predicts the repeat as
well as the noise allows.

Significance. The statistic is the *median* over the held-out trials of ``ln ratio_i``, so
the verdict never rests on one or two trials (a voluntary contraction or a spike in one
trial moves a mean, not the median). Its standard error is ``1.2533 s / sqrt(n)`` with ``s``
the larger of the spread expected from the effective sample counts of window and lead-in
(``2 / N_eff`` per power estimate) and the observed robust spread (1.4826 MAD) of the
trials' log-ratios. A gap is *significant* when the median exceeds ``significance_z``
standard errors and the gap beyond noise is at least ``min_beyond_noise_pct`` (NRMSE
points of the response: below that no physiologist would call the twin wrong).

Narrow-band components. The mean periodogram of the held-out residual is searched for
peaks above a running-median background. A peak as narrow as the frequency resolution, at
the same frequency in every trial, is an instrument line (mains, the stimulator's carrier or
their aliases): listed, not counted. A wider peak (a physiological oscillation, e.g.
tremor at 8-12 Hz) whose power beyond the background is material is an unexplained
component and makes the remaining gap significant.

Verdict. ``none``: the nominal gap is not significant (a candidate that would fit a gap
within noise is reported as such, not named). ``effect`` / ``pair``: a candidate (pair) is
supported and the nominal gap is significant; ``remaining`` then says whether what it
leaves is still significant. ``unexplained``: the nominal gap is significant and no
candidate or pair is supported.
"""

from __future__ import annotations

import math

import numpy as np

from nmsid.analysis.gap.fit import find_steps
from nmsid.analysis.gap.harmonics import local_harmonics
from nmsid.analysis.gap.models import nuisance_basis
from nmsid.analysis.gap.samples import effective_fraction

#: Residual harmonics examined (1.5f: a non-harmonic reference).
HARMONIC_ORDERS = (1, 1.5, 2, 3)

#: Plain words for each effect (the report's sentence).
EFFECT_WORDS = {
    "dead_time": "a dead time (the force answers the stimulation late)",
    "activation_dynamics": "slower muscle activation (a first-order lag before the "
                           "force dynamics)",
    "fatigue": "fatigue (the response weakens with accumulated stimulation)",
    "recruitment_nonlinearity": "non-linear motor-unit recruitment",
    "baseline_drift": "a wandering or jumping baseline force",
    "flexor_extensor_asymmetry": "different dynamics of flexor and extensor",
}


def effect_words(label: str) -> str:
    """Plain words for an effect or a pair label ``a+b``."""
    return " together with ".join(EFFECT_WORDS.get(p, p) for p in label.split("+"))


def _mad_sd(x: np.ndarray) -> float:
    return 1.4826 * float(np.median(np.abs(x - np.median(x)))) if len(x) else float("nan")


def gap_test(resid: np.ndarray, noise_N2: np.ndarray, reference: np.ndarray,
             nu_window: float, nu_lead: float, n_lead: int, *, z_crit: float = 3.0,
             min_beyond_noise_pct: float = 0.1, names=None) -> dict:
    """Is a residual significantly beyond the noise? (see module)

    Parameters
    ----------
    resid : (n_trials, n_eval) ndarray
        Held-out residual of the model, one row per tested trial.
    noise_N2 : (n_trials,) ndarray
        Each trial's noise power from its steady lead-in.
    reference : (n_trials, n_eval) ndarray
        The measured force (offset and trend removed): the NRMSE's denominator.
    nu_window, nu_lead : float
        Effective-sample fractions of the noise at the evaluation rate.
    n_lead : int
        Samples of a lead-in segment.
    names : list of str, optional
        Trial names (for the concentration note).

    Returns
    -------
    dict
        ``beyond_noise_pct`` (all trials), ``beyond_noise_pct_typical`` (from the median
        ratio), ``median_ratio``, ``z``, ``significant``, ``concentrated_in`` (trials that
        carry more than half of the excess, when at most two do) and ``n_trials``.

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> noise = rng.normal(0, 0.1, (30, 1000))
    >>> ref = np.sin(np.linspace(0, 60, 1000))[None, :].repeat(30, 0)
    >>> gap_test(noise, np.full(30, 0.01), ref, 0.5, 0.5, 300)["significant"]
    False
    >>> gap_test(noise + 0.05, np.full(30, 0.01), ref, 0.5, 0.5, 300)["significant"]
    True
    """
    ok = np.isfinite(noise_N2) & (noise_N2 > 0)
    out = {"n_trials": int(ok.sum()), "significant": False, "beyond_noise_pct": None,
           "beyond_noise_pct_typical": None, "median_ratio": None, "z": None,
           "concentrated_in": []}
    if ok.sum() < 3:
        out["note"] = "fewer than three trials with a measurable lead-in noise: not tested"
        return out
    r, N, ref = resid[ok], noise_N2[ok], reference[ok]
    P = np.mean(r ** 2, axis=1)
    ref_ms = float(np.mean(ref ** 2))
    lr = np.log(P / N)
    n = len(lr)
    n_win = max(1.0, nu_window * r.shape[1])
    n_ld = max(1.0, nu_lead * n_lead)
    s_expected = math.sqrt(2.0 / n_win + 2.0 / n_ld)
    s = max(s_expected, _mad_sd(lr))
    med = float(np.median(lr))
    z = med / (1.2533 * s / math.sqrt(n))
    beyond_all = 100.0 * math.sqrt(max(float(np.mean(P - N)), 0.0) / ref_ms)
    beyond_typ = 100.0 * math.sqrt(max(math.expm1(med), 0.0) * float(np.median(N)) / ref_ms)
    excess = np.maximum(P - N, 0.0)
    total = float(excess.sum())
    conc = []
    if total > 0 and beyond_all >= max(min_beyond_noise_pct, 2.0 * beyond_typ):
        order = np.argsort(excess)[::-1]
        for k in (1, 2):
            if float(excess[order[:k]].sum()) > 0.5 * total:
                idx = np.flatnonzero(ok)[order[:k]]
                conc = [str(names[i]) if names is not None else int(i) for i in idx]
                out["concentrated_share_pct"] = 100.0 * float(excess[order[:k]].sum()) / total
                break
    out.update({"beyond_noise_pct": beyond_all, "beyond_noise_pct_typical": beyond_typ,
                "median_ratio": math.exp(med), "z": z, "concentrated_in": conc,
                "significant": bool(z > z_crit and beyond_typ >= min_beyond_noise_pct)})
    return out


def narrow_band(resid: np.ndarray, reference: np.ndarray, noise: np.ndarray | None,
                fs_Hz: float, f_max_Hz: float, *, f_min_Hz: float = 1.0,
                peak_ratio: float = 2.0,
                line_width_Hz: float = 0.45, min_beyond_noise_pct: float = 0.1) -> list[dict]:
    """Narrow-band components of a residual (see module): frequency, width, kind, size.

    Parameters
    ----------
    resid : (n_trials, n) ndarray
    reference : (n_trials, n) ndarray
    noise : (n_trials, m) ndarray or None
        Lead-in noise rows: is the component there at rest too?
    fs_Hz, f_max_Hz : float
        Sampling rate and the top of the analysed band.

    Returns
    -------
    list of dict
        ``f_Hz``, ``width_Hz``, ``kind`` (``line`` or ``band``), ``beyond_noise_pct``,
        ``trial_spread_Hz`` (interquartile range of the trials' peak frequencies), ``at_rest``
        (its power in the lead-in relative to the lead-in background, or None),
        ``significant`` (a material band).

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(1)
    >>> t = np.arange(1000) / 100.0
    >>> r = rng.normal(0, 0.1, (20, 1000)) + 0.2 * np.sin(2 * np.pi * 5.0 * t)
    >>> c = narrow_band(r, np.ones((20, 1000)), None, 100.0, 25.0)
    >>> [(round(x["f_Hz"], 1), x["kind"]) for x in c]
    [(5.0, 'line')]
    """
    n = resid.shape[1]
    if resid.shape[0] == 0 or n < 64:
        return []
    win = np.hanning(n)
    norm = float(np.sum(win ** 2))
    P = np.mean(np.abs(np.fft.rfft(resid * win, axis=1)) ** 2, axis=0) / norm
    f = np.fft.rfftfreq(n, 1.0 / fs_Hz)
    df = f[1]
    use = (f >= f_min_Hz) & (f <= f_max_Hz)
    # background: the log-spectrum's smooth trend (cubic over the band) plus a running
    # 35th percentile of what is left over +-4 Hz, so that a peak a few Hz wide (tremor)
    # does not raise its own background, and the filter's roll-off is no peak
    L = np.log(np.maximum(P, 1e-300))
    fu = f[use]
    if use.sum() < 16:
        return []
    coef = np.polyfit(fu, L[use], 3)
    trend = np.polyval(coef, f)
    R = L - trend
    half = max(3, int(round(4.0 / df)))
    pad = np.pad(R, half, mode="reflect")
    bgR = np.array([np.percentile(pad[i:i + 2 * half + 1], 35) for i in range(len(P))])
    bg = np.exp(trend + bgR)
    hot = use & (P > peak_ratio * bg)
    ref_ms = float(np.mean(reference ** 2))
    # groups of hot bins; gaps under 0.5 Hz joined (one component may dip in places)
    idx = np.flatnonzero(hot)
    groups: list[list[int]] = []
    for k in idx:
        if groups and (k - groups[-1][-1]) * df < 0.5:
            groups[-1].append(int(k))
        else:
            groups.append([int(k)])
    Pt = np.abs(np.fft.rfft(resid * win, axis=1)) ** 2          # per trial
    out = []
    for g in groups:
        i, j = g[0], g[-1]
        sl = slice(i, j + 1)
        ex = np.maximum(P[sl] - bg[sl], 0.0)
        if ex.sum() <= 0:
            continue
        kp = i + int(np.argmax(ex))
        top = P[kp] - bg[kp]
        a = b = kp
        while a - 1 >= i and P[a - 1] - bg[a - 1] >= 0.5 * top:
            a -= 1
        while b + 1 <= j and P[b + 1] - bg[b + 1] >= 0.5 * top:
            b += 1
        width = float((b - a + 1) * df)                     # half-power width
        fc = float(np.sum(f[sl] * ex) / ex.sum())
        if width > fc / 2:      # not an oscillation: a broad low-frequency excess
            continue
        # a line sits at the same frequency in every trial; an oscillation wanders
        lo_k, hi_k = max(i - 3, 1), min(j + 4, len(P))
        peaks = f[lo_k + np.argmax(Pt[:, lo_k:hi_k], axis=1)]
        spread = float(np.subtract(*np.percentile(peaks, [75, 25])))
        if width <= line_width_Hz and spread <= 2 * df:
            kind = "line"
        elif width < 2.5 * df:  # a bin or two, wandering: neither a line nor an oscillation
            continue
        else:
            kind = "band"
        # power per bin -> mean square: Parseval with the window's normalisation, 2 sides
        ms = 2.0 * float(ex.sum()) / n
        beyond = 100.0 * math.sqrt(ms / ref_ms) if ref_ms > 0 else float("nan")
        at_rest = None
        if noise is not None and noise.shape[1] >= 32:
            m = noise.shape[1]
            wn = np.hanning(m)
            Pn = np.mean(np.abs(np.fft.rfft(noise * wn, axis=1)) ** 2, axis=0)
            fn = np.fft.rfftfreq(m, 1.0 / fs_Hz)
            near = (fn >= f[a] - df) & (fn <= f[b] + df)
            away = (fn > 0.5) & (np.abs(fn - fc) > 3.0) & (np.abs(fn - fc) < 8.0)
            if near.any() and away.any():
                at_rest = float(np.mean(Pn[near]) / np.median(Pn[away]))
        out.append({"f_Hz": fc, "width_Hz": width, "kind": kind, "beyond_noise_pct": beyond,
                    "trial_spread_Hz": spread, "at_rest": at_rest,
                    "significant": bool(kind == "band" and beyond >= min_beyond_noise_pct
                                        and top >= 3 * bg[kp])})
    out.sort(key=lambda c: -c["beyond_noise_pct"])
    return out[:6]


def decide(nominal_significant: bool, kind: str, remaining_significant: bool) -> str:
    """The verdict from three facts (see module).

    Parameters
    ----------
    nominal_significant : bool
        The nominal model's held-out gap is significant.
    kind : {"none", "effect", "pair"}
        What the candidate search supports.
    remaining_significant : bool
        What the final model leaves is significant (for ``none`` the nominal's).

    Examples
    --------
    >>> decide(False, "effect", False), decide(True, "none", True), decide(True, "pair", True)
    ('none', 'unexplained', 'pair')
    """
    if kind not in ("none", "effect", "pair"):
        raise ValueError(f"kind = {kind!r}: use 'none', 'effect' or 'pair'")
    if not nominal_significant and not remaining_significant:
        return "none"
    if kind == "none":
        return "unexplained"
    return kind if nominal_significant else "none"


def sentence(verdict: str, label: str | None, nominal: dict, remaining: dict) -> str:
    """The verdict in one or two sentences a physiologist understands."""
    rem = remaining.get("beyond_noise_pct_typical") or 0.0
    nom = nominal.get("beyond_noise_pct_typical") or 0.0
    where = remaining.get("where_summary") or ""
    conc = remaining.get("concentrated_in") or nominal.get("concentrated_in") or []
    steps = {s["trial"]: s for s in (remaining.get("where") or {}).get("baseline_steps", [])
             if s["share_of_excess_pct"] >= 80}
    tail = ""
    if conc:
        tail = (f" The largest part of the misfit sits in trial(s) {', '.join(map(str, conc))}"
                "; the verdict does not rest on them")
        explained = [c for c in conc if c in steps]
        if explained:
            tail += "; " + ", ".join(
                f"{c} has a baseline step of {steps[c]['height_N']:+.2f} N at "
                f"{steps[c]['t_s']:.1f} s into the chirp" for c in explained)
        if len(explained) < len(conc):
            tail += " - check those trials for a voluntary contraction or an artefact"
        tail += "."
    if verdict == "none":
        return ("The nominal second-order model predicts held-out repeats as well as the "
                f"measurement noise allows (what it misses beyond noise, {nom:.2f} % of the "
                "response, is not significant): no unmodelled effect is needed." + tail)
    if verdict == "unexplained":
        return ("The nominal model misses part of the response "
                f"({nom:.2f} % of the response beyond noise, significant), and none of the "
                "six candidate effects, alone or in pairs, explains it: something else is at "
                f"work{(' - ' + where) if where else ''}." + tail)
    words = effect_words(label or "")
    text = (f"Adding {words} explains the gap: what the model misses beyond noise falls from "
            f"{nom:.2f} % to {rem:.2f} % of the response")
    if remaining.get("significant"):
        text += (f", but that remainder is still significant{(' - ' + where) if where else ''}"
                 f": {words.split(' (')[0]} is only part of the story.")
    else:
        text += ", which is within noise."
    return text + tail


def _ratio_rows(resid: np.ndarray, noise_N2: np.ndarray) -> np.ndarray:
    return np.mean(resid ** 2, axis=1) / noise_N2


def where(diag, resid: np.ndarray, components: list[dict], harmonics: dict | None) -> dict:
    """Where a held-out residual exceeds the noise: by sE, chirp band, trial position; its
    narrow-band components and harmonics; and a one-line summary."""
    d = diag.data
    ok = diag.tested & np.isfinite(d.steady_noise_N2) & (d.steady_noise_N2 > 0) \
        if d.steady_noise_N2 is not None else np.zeros(d.n_trials, bool)
    out: dict = {"sE": [], "chirp_band": [], "trial_position": {}, "narrow_band": components,
                 "harmonics": harmonics}
    if ok.sum() < 3:
        out["summary"] = ""
        return out
    N = d.steady_noise_N2
    ratio = _ratio_rows(resid[ok], N[ok])
    lev = d.level[ok]
    for j, sE in enumerate(d.sE_levels):
        m = lev == j
        if m.any():
            out["sE"].append({"sE": float(sE), "ratio_to_noise": float(np.median(ratio[m])),
                              "n_trials": int(m.sum())})
    edges = diag.settings.bands_Hz
    f = d.f_inst_Hz
    mean_N = float(np.mean(N[ok]))
    for lo, hi in zip(edges[:-1], edges[1:]):
        m = (f >= lo) & (f < hi if hi < edges[-1] else f <= hi)
        if m.any():
            out["chirp_band"].append({"f_lo_Hz": lo, "f_hi_Hz": hi, "ratio_to_noise":
                                      float(np.mean(resid[ok][:, m] ** 2)) / mean_N})
    order = d.order[ok]
    thirds = np.array_split(np.argsort(order), 3)
    out["trial_position"] = {
        "ratio_to_noise_by_third": [float(np.median(ratio[t])) if len(t) else None
                                    for t in thirds],
        "correlation_with_order": float(np.corrcoef(order, np.log(ratio))[0, 1])
        if len(ratio) >= 3 and np.std(np.log(ratio)) > 0 else None}
    out["summary"] = _summary(out)
    return out


def baseline_steps(diag, resid: np.ndarray) -> list[dict]:
    """Baseline steps inside held-out trials (a jump at an unknown time): trial, time after
    the chirp's start, height, and how much of the trial's misfit beyond noise it carries."""
    d = diag.data
    ok = np.flatnonzero(diag.tested)
    if len(ok) == 0:
        return []
    Q = nuisance_basis(d.t_eval_s, 0.0)
    r = resid[ok]
    info: dict = {}
    steps = find_steps(r, Q, d.subset(ok), info=info)
    out = []
    for i, u in steps.items():
        a = float(r[i] @ u)
        after = r[i] - a * u
        N = d.steady_noise_N2[ok[i]] if d.steady_noise_N2 is not None else 0.0
        ex_before = max(float(np.mean(r[i] ** 2)) - N, 1e-30)
        ex_after = max(float(np.mean(after ** 2)) - N, 0.0)
        k, scale = info[i]
        height = a * scale
        out.append({"trial": d.trials[ok[i]].name, "t_s": float(d.t_eval_s[k]),
                    "height_N": height,
                    "share_of_excess_pct": 100.0 * (1 - ex_after / ex_before)})
    return out


def _summary(w: dict) -> str:
    parts = []
    bands = w["chirp_band"]
    if bands:
        vals = np.array([b["ratio_to_noise"] for b in bands])
        k = int(np.argmax(vals))
        if vals[k] > 1.5 and vals[k] > 1.5 * np.median(vals):
            parts.append(f"mostly in the {bands[k]['f_lo_Hz']:g}-{bands[k]['f_hi_Hz']:g} Hz "
                         "part of the chirp")
    levels = w["sE"]
    if levels:
        vals = np.array([s["ratio_to_noise"] for s in levels])
        k = int(np.argmax(vals))
        if vals[k] > 1.5 and vals[k] > 1.5 * np.median(vals):
            parts.append(f"largest at sE = {levels[k]['sE']:g}")
    tp = w["trial_position"]
    c = tp.get("correlation_with_order")
    if c is not None and abs(c) > 0.5:
        parts.append("growing through the session" if c > 0 else "largest early in the session")
    for comp in w["narrow_band"]:
        if comp["significant"]:
            rest = comp.get("at_rest")
            parts.append(f"an oscillation near {comp['f_Hz']:.1f} Hz "
                         f"({comp['width_Hz']:.1f} Hz wide"
                         + (", present at rest too: not a response to the stimulation"
                            if rest is not None and rest > 2 else "") + ")")
    h = w.get("harmonics") or {}
    if h.get("excess"):
        parts.append(f"distortion at {' and '.join(h['excess'])} the chirp frequency "
                     "(a non-linearity)")
    return "; ".join(parts)


def _harmonics(diag, res) -> dict | None:
    d = diag.data
    ok = diag.tested
    args = (d.phase_eval_rad, d.f_inst_Hz, d.t_eval_s)
    try:
        hm = local_harmonics(diag.reference[ok], *args, orders=(1,))
        hr = local_harmonics(res.heldout_resid[ok], *args, orders=HARMONIC_ORDERS)
    except (ValueError, IndexError, FloatingPointError):
        return None
    fund = np.abs(hm.amplitude[:, :, 0])
    rel = np.abs(hr.amplitude) / fund[:, :, None]
    h = {f"{o:g}f": float(np.nanmedian(100 * rel[:, :, k]))
         for k, o in enumerate(HARMONIC_ORDERS)}
    ref = h.get("1.5f", float("nan"))
    excess = [k for k in ("2f", "3f") if k in h and np.isfinite(ref) and h[k] > 2.5 * ref
              and h[k] > 0.5]
    return {"median_residual_pct": h, "excess": excess}


def assess(diag) -> dict:
    """Verdict, the nominal gap and the remaining gap of a diagnosis (see module)."""
    d = diag.data
    s = diag.settings
    if d.steady_N is not None and d.steady_N.shape[1] >= 16:
        nu = effective_fraction(d.steady_N, d.fs_eval_Hz, d.settings.lowpass_Hz)
        n_lead = int(d.steady_N.shape[1])
    else:
        nu, n_lead = 2 * d.settings.lowpass_Hz / d.fs_eval_Hz, 1
    ok = diag.tested
    noise = d.steady_noise_N2 if d.steady_noise_N2 is not None else np.full(d.n_trials, np.nan)
    names = [d.trials[i].name for i in np.flatnonzero(ok)]
    band_top = min(d.settings.lowpass_Hz, d.fs_eval_Hz / 2)
    rest = d.steady_N[ok] if d.steady_N is not None else None

    def test(res):
        r = res.heldout_resid[ok]
        t = gap_test(r, noise[ok], diag.reference[ok], nu, nu, n_lead, z_crit=s.significance_z,
                     min_beyond_noise_pct=s.min_beyond_noise_pct, names=names)
        comps = narrow_band(r, diag.reference[ok], rest, d.fs_eval_Hz, band_top,
                            f_min_Hz=d.chirp_f0_Hz, min_beyond_noise_pct=s.min_beyond_noise_pct)
        t["narrow_band_significant"] = any(c["significant"] for c in comps)
        t["significant_total"] = bool(t["significant"] or t["narrow_band_significant"])
        return t, comps

    nom, nom_comps = test(diag.nominal)
    final = diag.best_pair or diag.best
    kind = "none" if final is None else ("pair" if diag.best_pair is not None else "effect")
    if final is None:
        rem, comps, res = nom, nom_comps, diag.nominal
    else:
        (rem, comps), res = test(final), final
    verdict = decide(nom["significant_total"], kind, rem["significant_total"])
    if verdict == "none":      # nothing named: what remains is the nominal model's gap
        rem, comps, res = nom, nom_comps, diag.nominal
    w = where(diag, res.heldout_resid, comps, _harmonics(diag, res))
    w["baseline_steps"] = baseline_steps(diag, diag.nominal.heldout_resid)
    rem = dict(rem)
    rem["where"] = w
    rem["where_summary"] = w["summary"]
    label = final.label if final is not None else None
    remaining = {"beyond_noise_pct": rem["beyond_noise_pct"],
                 "beyond_noise_pct_typical": rem["beyond_noise_pct_typical"],
                 "significant": rem["significant_total"],
                 "broadband_significant": rem["significant"],
                 "narrow_band_significant": rem["narrow_band_significant"],
                 "median_ratio_to_noise": rem["median_ratio"], "z": rem["z"],
                 "concentrated_in": rem["concentrated_in"],
                 "concentrated_share_pct": rem.get("concentrated_share_pct"),
                 "n_trials": rem["n_trials"], "where": w}
    nominal = {k: nom.get(k) for k in ("beyond_noise_pct", "beyond_noise_pct_typical",
                                        "median_ratio", "z", "significant_total",
                                        "concentrated_in", "concentrated_share_pct",
                                        "n_trials")}
    nominal["significant"] = nominal.pop("significant_total")
    if verdict == "none" and final is not None:
        note = (f"{label} would fit, but the gap it would explain is within noise "
                f"(nominal gap beyond noise {nom['beyond_noise_pct_typical'] or 0:.2f} %, "
                "not significant): not named")
    else:
        note = None
    text = sentence(verdict, label, nom, dict(rem, where_summary=w["summary"], where=w))
    return {"verdict": verdict, "label": label if verdict in ("effect", "pair") else None,
            "remaining": remaining, "nominal_gap": nominal, "sentence": text,
            "not_named": note}
