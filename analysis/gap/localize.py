"""Where the simulation misses: the held-out gap broken down by location.

Every figure here is computed on held-out predictions only (each trial predicted by the
fold that did not train on it). Locations: sE level, chirp frequency band (the
instantaneous chirp frequency maps each time sample to a frequency), the trial's position
in the session (order and cumulative stimulation), and the sign and size of the commanded
deviation ``rE - 0.5``; in the frequency domain, the transfer-function error (gain and
phase of measured over simulated, window by window along the chirp, with the coherence of
the measurement as the noise floor), the residual's harmonics of the chirp frequency (2f,
3f, against a non-harmonic 1.5f as the noise reference) and the residual's power below the
chirp band.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from itertools import pairwise
from typing import Any

import numpy as np

from nmsid.analysis.gap.diagnose import CandidateResult, Diagnosis
from nmsid.analysis.gap.harmonics import local_harmonics

HARMONIC_ORDERS = (1, 1.5, 2, 3)


def _nrmse(r: np.ndarray, ref: np.ndarray) -> float:
    den = float(np.sum(ref ** 2))
    return 100.0 * float(np.sqrt(np.sum(r ** 2) / den)) if den > 0 else float("nan")


def _plain(obj: Any) -> Any:
    """``to_dict`` of a result object, lists for tuples, recursively (the report's form)."""
    if hasattr(obj, "to_dict"):
        return obj.to_dict()
    if isinstance(obj, dict):
        return {k: _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plain(v) for v in obj]
    return obj


@dataclass(frozen=True)
class LocationTable:
    """Held-out misfit of one model at every location (:func:`by_location`).

    Each row is the report's mapping (``gap_report.json``, ``localization``; docs/gap.md).

    Attributes
    ----------
    sE : tuple of dict
        Per sE level: ``sE``, ``nrmse_pct``, ``residual_power_N2`` (N^2), ``n_trials``.
    band : tuple of dict
        Per chirp-frequency band: ``f_lo_Hz``, ``f_hi_Hz``, ``nrmse_pct``,
        ``residual_power_N2``.
    position : tuple of dict
        Per held-out trial in session order: ``trial``, ``order``, ``sE``, ``repeat``,
        ``cum_stim_s``, ``nrmse_pct``, ``residual_power_N2``.
    deviation : tuple of dict
        Per bin of the commanded deviation ``rE - 0.5``: ``d_lo``, ``d_hi``,
        ``nrmse_pct``, ``residual_rms_N``, ``residual_mean_N``.
    """

    sE: tuple[dict, ...]
    band: tuple[dict, ...]
    position: tuple[dict, ...]
    deviation: tuple[dict, ...]

    def to_dict(self) -> dict:
        """The report's form: ``{"sE": [...], "band": [...], ...}``."""
        return {f.name: [dict(row) for row in getattr(self, f.name)] for f in fields(self)}


@dataclass(frozen=True)
class FrequencyView:
    """Transfer-function error and residual harmonics along the chirp
    (:func:`frequency_view`), medians over the held-out trials, one entry per window.

    Attributes
    ----------
    f_Hz : tuple of float
        Window centre frequencies of the chirp.
    gain_error_dB, phase_error_deg : tuple of float
        Measured over simulated fundamental (dB, degrees).
    coherence : tuple of float
        The measurement's coherence with the chirp (the noise floor of the two above).
    residual_harmonic_pct : dict of str to list of float
        The residual's ``1f``, ``1.5f`` (non-harmonic noise reference), ``2f`` and ``3f``
        components, % of the measured fundamental.
    measured_harmonic_pct : dict of str to list of float
        The measurement's own ``1.5f``, ``2f`` and ``3f`` components, same unit.
    """

    f_Hz: tuple[float, ...]
    gain_error_dB: tuple[float, ...]
    phase_error_deg: tuple[float, ...]
    coherence: tuple[float, ...]
    residual_harmonic_pct: dict[str, list[float]]
    measured_harmonic_pct: dict[str, list[float]]

    def to_dict(self) -> dict:
        """The report's form (``gap_report.json``, ``frequency.nominal``)."""
        return {f.name: _plain(getattr(self, f.name)) for f in fields(self)}


@dataclass(frozen=True)
class ResidualSpectrum:
    """Mean periodogram of a held-out residual and its power below the chirp band
    (:func:`residual_spectrum`).

    Attributes
    ----------
    f_Hz : tuple of float
    power : tuple of float
        Mean Hann-windowed periodogram of the residual (N^2 per bin, unnormalised).
    low_share : float
        Share of the in-band power (0 < f <= low-pass) below the chirp's start frequency.
    low_share_if_white : float
        The same share for white noise.
    low_excess : float or None
        ``low_share / low_share_if_white`` (baseline drift shows as >> 1).
    """

    f_Hz: tuple[float, ...]
    power: tuple[float, ...]
    low_share: float
    low_share_if_white: float
    low_excess: float | None

    def to_dict(self) -> dict:
        """The report's form (``f_Hz`` and ``power`` go to the figures only)."""
        return {f.name: _plain(getattr(self, f.name)) for f in fields(self)}


def by_location(diag: Diagnosis, res: CandidateResult) -> LocationTable:
    """Held-out NRMSE (%) and residual power (N^2) of one model at every location.

    Parameters
    ----------
    diag : Diagnosis
        The session's diagnosis (its held-out trials, reference and settings).
    res : CandidateResult
        The model (nominal, candidate or pair) whose held-out residual is broken down.

    Returns
    -------
    LocationTable
    """
    d = diag.data
    ok = diag.tested
    r = res.heldout_resid
    ref = diag.reference
    lev = d.level
    out: dict[str, list[dict]] = {"sE": [], "band": [], "position": [], "deviation": []}
    for j, sE in enumerate(d.sE_levels):
        rows = np.flatnonzero(ok & (lev == j))
        if len(rows):
            out["sE"].append({"sE": float(sE), "nrmse_pct": _nrmse(r[rows], ref[rows]),
                              "residual_power_N2": float(np.mean(r[rows] ** 2)),
                              "n_trials": int(len(rows))})
    edges = diag.settings.bands_Hz
    f = d.f_inst_Hz
    for lo, hi in pairwise(edges):
        m = (f >= lo) & (f < hi if hi < edges[-1] else f <= hi)
        if np.any(m):
            out["band"].append({"f_lo_Hz": lo, "f_hi_Hz": hi,
                                "nrmse_pct": _nrmse(r[ok][:, m], ref[ok][:, m]),
                                "residual_power_N2": float(np.mean(r[ok][:, m] ** 2))})
    for i in np.flatnonzero(ok):
        t = d.trials[i]
        out["position"].append({"trial": t.name, "order": t.order, "sE": t.sE,
                                "repeat": t.repeat, "cum_stim_s": t.cum_stim_s,
                                "nrmse_pct": _nrmse(r[i], ref[i]),
                                "residual_power_N2": float(np.mean(r[i] ** 2))})
    dev = d.d_eval
    e = diag.settings.deviation_edges
    for lo, hi in pairwise(e):
        m = ok[:, None] & (dev >= lo) & ((dev < hi) if hi < e[-1] else (dev <= hi))
        if np.any(m):
            out["deviation"].append({"d_lo": lo, "d_hi": hi,
                                     "nrmse_pct": _nrmse(r[m], ref[m]),
                                     "residual_rms_N": float(np.sqrt(np.mean(r[m] ** 2))),
                                     "residual_mean_N": float(np.mean(r[m]))})
    return LocationTable(**{k: tuple(v) for k, v in out.items()})


def trial_gain_ratios(diag: Diagnosis, res: CandidateResult) -> np.ndarray:
    """Per trial: least-squares scale of the measured force on the model's held-out
    prediction (1 = right gain; a fall with cumulative stimulation is fatigue)."""
    pred = diag.reference - res.heldout_resid
    num = np.sum(pred * diag.reference, axis=1)
    den = np.sum(pred * pred, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(diag.tested & (den > 0), num / den, np.nan)


def frequency_view(diag: Diagnosis, res: CandidateResult) -> FrequencyView:
    """Transfer-function error and residual harmonics along the chirp (medians over the
    held-out trials).

    Parameters
    ----------
    diag : Diagnosis
    res : CandidateResult
        The model whose held-out prediction is compared with the measurement.

    Returns
    -------
    FrequencyView
    """
    d = diag.data
    ok = diag.tested
    ref = diag.reference[ok]
    pred = ref - res.heldout_resid[ok]
    args = (d.phase_eval_rad, d.f_inst_Hz, d.t_eval_s)
    hm = local_harmonics(ref, *args, orders=HARMONIC_ORDERS)
    hp = local_harmonics(pred, *args, orders=(1,))
    hr = local_harmonics(res.heldout_resid[ok], *args, orders=HARMONIC_ORDERS)
    ratio = hm.amplitude[:, :, 0] / hp.amplitude[:, :, 0]
    fund = np.abs(hm.amplitude[:, :, 0])
    rel = np.abs(hr.amplitude) / fund[:, :, None]
    return FrequencyView(
        f_Hz=tuple(hm.f_Hz.tolist()),
        gain_error_dB=tuple(np.median(20 * np.log10(np.abs(ratio)), axis=0).tolist()),
        phase_error_deg=tuple(np.degrees(np.angle(np.median(ratio / np.abs(ratio), axis=0))
                                         ).tolist()),
        coherence=tuple(np.median(hm.coherence, axis=0).tolist()),
        residual_harmonic_pct={
            f"{o:g}f": (100 * np.median(rel[:, :, k], axis=0)).tolist()
            for k, o in enumerate(HARMONIC_ORDERS)},
        measured_harmonic_pct={
            f"{o:g}f": (100 * np.median(np.abs(hm.amplitude[:, :, k]) / fund, axis=0)).tolist()
            for k, o in enumerate(HARMONIC_ORDERS) if o != 1},
    )


def residual_spectrum(diag: Diagnosis, res: CandidateResult) -> ResidualSpectrum:
    """Mean periodogram of the held-out residual (offset and trend removed), and the share
    of its power below the chirp band against what white noise would put there.

    Parameters
    ----------
    diag : Diagnosis
    res : CandidateResult

    Returns
    -------
    ResidualSpectrum
    """
    d = diag.data
    r = res.heldout_resid[diag.tested]
    n = r.shape[1]
    win = np.hanning(n)
    P = np.mean(np.abs(np.fft.rfft(r * win, axis=1)) ** 2, axis=0)
    f = np.fft.rfftfreq(n, 1.0 / d.fs_eval_Hz)
    band = d.settings.lowpass_Hz
    low = (f > 0) & (f < d.chirp_f0_Hz)
    inband = (f > 0) & (f <= band)
    share = float(P[low].sum() / P[inband].sum()) if P[inband].sum() > 0 else float("nan")
    white = float(low.sum() / inband.sum())
    return ResidualSpectrum(f_Hz=tuple(f.tolist()), power=tuple(P.tolist()), low_share=share,
                            low_share_if_white=white,
                            low_excess=share / white if white else None)


@dataclass
class Localization:
    """Where the gap sits, for the nominal model and (if any) the winner.

    Attributes
    ----------
    nominal : LocationTable
        :func:`by_location` of the nominal model.
    candidates : dict of str to LocationTable
        :func:`by_location` of every candidate and pair, by label (how far each shrinks
        the gap where).
    gain_vs_stimulation : dict
        Each trial's gain relative to its level against cumulative stimulation
        (``cum_stim_s``, ``gain_ratio``, ``slope_per_100s``, ``correlation``).
    frequency : dict of str to FrequencyView
        :func:`frequency_view` under ``nominal`` and ``augmented`` (the report adds the
        winner's ``footprint``, a plain mapping of ``f_Hz``, ``gain_error_dB`` and
        ``phase_error_deg``).
    spectrum : dict of str to ResidualSpectrum
        :func:`residual_spectrum` under ``nominal`` and ``augmented``.
    augmented : LocationTable or None
        :func:`by_location` of the winner (None: nothing beat the nominal model).
    augmented_effect : str or None
        The winner's label.
    """

    nominal: LocationTable
    candidates: dict[str, LocationTable]
    gain_vs_stimulation: dict
    frequency: dict[str, Any]
    spectrum: dict[str, ResidualSpectrum]
    augmented: LocationTable | None = None
    augmented_effect: str | None = None

    def to_dict(self) -> dict:
        """The report's form (``augmented`` keys only when there is a winner)."""
        return {k: _plain(v) for k, v in vars(self).items() if v is not None}


def localization(diag: Diagnosis) -> Localization:
    """Everything above for the nominal model and (if any) the winner, plus per-location
    tables for every candidate."""
    out: dict[str, Any] = {"nominal": by_location(diag, diag.nominal)}
    final = diag.best_pair or diag.best
    if final is not None:
        out["augmented"] = by_location(diag, final)
        out["augmented_effect"] = final.label
    out["candidates"] = {r.label: by_location(diag, r) for r in diag.candidates + diag.pairs}
    g = trial_gain_ratios(diag, diag.nominal)
    ok = np.isfinite(g)
    c = diag.data.cum_stim_s
    slope = float(np.polyfit(c[ok], g[ok], 1)[0]) if ok.sum() >= 3 else float("nan")
    # within-sE deviations only (the per-sE gains absorb between-level differences)
    out["gain_vs_stimulation"] = {
        "cum_stim_s": c[ok].tolist(), "gain_ratio": g[ok].tolist(),
        "slope_per_100s": 100 * slope,
        "correlation": float(np.corrcoef(c[ok], g[ok])[0, 1]) if ok.sum() >= 3 else None}
    out["frequency"] = {"nominal": frequency_view(diag, diag.nominal)}
    out["spectrum"] = {"nominal": residual_spectrum(diag, diag.nominal)}
    if final is not None:
        out["frequency"]["augmented"] = frequency_view(diag, final)
        out["spectrum"]["augmented"] = residual_spectrum(diag, final)
    return Localization(**out)
