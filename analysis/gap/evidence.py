"""The signatures that back a diagnosis, and how confusable candidates were told apart.

Signatures, read from the nominal model's held-out residual:

- dead time: phase error growing *linearly* with frequency (``-360 f L`` degrees) and no
  gain error; an extra lag instead gives an *arctangent* phase error
  ``-atan(2 pi f tau)`` together with a gain roll-off ``-10 log10(1 + (2 pi f tau)^2)``;
- fatigue: the per-trial gain (measured over simulated) falling with cumulative
  stimulation;
- recruitment nonlinearity: harmonics of the chirp frequency (3f for the symmetric net
  drive, 2f if the muscles differ) above the non-harmonic 1.5f noise reference;
- baseline drift: residual power below the chirp band far above the white-noise share;
- flexor/extensor asymmetry: a gain/phase error with the shape of a second resonance.

The model comparison (held-out NRMSE and dIC of each candidate) is the decisive evidence;
the signatures say *why* and let a reader check it.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from nmsid.analysis.gap.diagnose import Diagnosis
from nmsid.analysis.gap.fit import Problem
from nmsid.analysis.gap.harmonics import local_harmonics
from nmsid.analysis.gap.localize import Localization
from nmsid.analysis.gap.models import FORMS, NOMINAL
from nmsid.protocols.effects import EFFECT_NAMES, EFFECTS, Effect


def confusable() -> tuple[tuple[Effect, Effect], ...]:
    """The pairs of registered effects that resemble each other in the data, as their
    modules declare them (``confusable_with``), in the registry's order of physics.

    Examples
    --------
    >>> (Effect.DEAD_TIME, Effect.ACTIVATION_DYNAMICS) in confusable()
    True
    """
    names = set(EFFECT_NAMES)
    out: list[tuple[Effect, Effect]] = []
    for s in EFFECTS:
        for other in s.source.params_type.confusable_with:
            if other not in names:
                continue                # its partner is not registered (now)
            pair = (s.effect, Effect(other))
            if pair not in out and pair[::-1] not in out:
                out.append(pair)
    return tuple(out)


@dataclass(frozen=True)
class PhaseShape:
    """A transfer-function error read as a dead time and as a first-order lag
    (:func:`phase_shape`).

    Attributes
    ----------
    dead_time_equivalent_s : float
        ``L`` of the least-squares line ``-360 f L`` (degrees) through the phase error.
    r2_linear_phase : float
        Share of the phase error's variance that line explains.
    lag_equivalent_s : float
        ``tau`` of the best arctangent ``-atan(2 pi f tau)`` (grid 0.1 ms - 0.3 s).
    r2_atan_phase : float
        Share of the variance the arctangent explains.
    gain_error_at_top_dB : float or None
        Gain error in the last window (None: no window).
    gain_rolloff_expected_for_lag_dB : float or None
        What that lag would make of it: ``-10 log10(1 + (2 pi f tau)^2)``.
    max_abs_phase_error_deg : float or None
    """

    dead_time_equivalent_s: float
    r2_linear_phase: float
    lag_equivalent_s: float
    r2_atan_phase: float
    gain_error_at_top_dB: float | None
    gain_rolloff_expected_for_lag_dB: float | None
    max_abs_phase_error_deg: float | None

    def to_dict(self) -> dict:
        """The report's form (``evidence.signatures.transfer_function``)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


def _view(freq: Any, key: str) -> np.ndarray:
    return np.asarray(freq[key] if isinstance(freq, Mapping) else getattr(freq, key), float)


def phase_shape(freq: Any) -> PhaseShape:
    """Fit the nominal model's phase error with a dead time (line through the origin)
    and with a first-order lag (arctangent plus its gain roll-off).

    Parameters
    ----------
    freq : FrequencyView or mapping
        ``f_Hz``, ``phase_error_deg`` and ``gain_error_dB`` (attributes of a
        :class:`~nmsid.analysis.gap.localize.FrequencyView`, or keys of a mapping).

    Returns
    -------
    PhaseShape
    """
    f = _view(freq, "f_Hz")
    ph = _view(freq, "phase_error_deg")
    g = _view(freq, "gain_error_dB")
    tot = float(np.sum((ph - ph.mean()) ** 2)) or 1e-12
    L = float(-(f @ ph) / (360.0 * (f @ f)))
    r2_lin = 1 - float(np.sum((ph + 360 * f * L) ** 2)) / tot
    taus = np.geomspace(1e-4, 0.3, 400)
    costs = [np.sum((ph + np.degrees(np.arctan(2 * np.pi * f * t))) ** 2) for t in taus]
    tau = float(taus[int(np.argmin(costs))])
    r2_atan = 1 - float(min(costs)) / tot
    g_lag = -10 * np.log10(1 + (2 * np.pi * f * tau) ** 2)
    return PhaseShape(dead_time_equivalent_s=L, r2_linear_phase=r2_lin,
                      lag_equivalent_s=tau, r2_atan_phase=r2_atan,
                      gain_error_at_top_dB=float(g[-1]) if len(g) else None,
                      gain_rolloff_expected_for_lag_dB=float(g_lag[-1]) if len(g_lag)
                      else None,
                      max_abs_phase_error_deg=float(np.max(np.abs(ph))) if len(ph) else None)


@dataclass(frozen=True)
class Footprint:
    """The winning effect's footprint on the transfer function (:func:`effect_footprint`).

    Attributes
    ----------
    f_Hz : tuple of float
        Centre frequency of each chirp window.
    gain_error_dB, phase_error_deg : tuple of float
        Median over trials of measured force over the model without the effect.
    shape : PhaseShape
        That error read as a dead time and as a lag (:func:`phase_shape`).
    """

    f_Hz: tuple[float, ...]
    gain_error_dB: tuple[float, ...]
    phase_error_deg: tuple[float, ...]
    shape: PhaseShape

    def to_dict(self) -> dict:
        """The report's form (``evidence.signatures.effect_footprint``): the three curves
        and the :class:`PhaseShape` fields side by side."""
        return {"f_Hz": list(self.f_Hz), "gain_error_dB": list(self.gain_error_dB),
                "phase_error_deg": list(self.phase_error_deg), **self.shape.to_dict()}


def effect_footprint(diag: Diagnosis) -> Footprint | None:
    """The winning effect's own footprint on the transfer function: measured force over
    the second-order model with the *augmented* fit's per-sE parameters but without the
    effect. A dead time leaves a phase line ``-360 f L`` and 0 dB; an extra lag an
    arctangent with its roll-off; an asymmetry the shape of the second muscle.

    Returns
    -------
    Footprint or None
        None when the final model adds no effect.
    """
    fit = diag.full_fit
    if not fit.candidate.effects:
        return None
    d = diag.data
    prob = Problem(d, NOMINAL)
    lev = prob.levels
    x = prob.unit_response(fit.wn_rad_s[lev], fit.zeta[lev], np.zeros(0))
    pred = prob.project(fit.Kp[d.level][:, None] * x)
    args = (d.phase_eval_rad, d.f_inst_Hz, d.t_eval_s)
    hm = local_harmonics(diag.reference, *args, orders=(1,))
    hp = local_harmonics(pred, *args, orders=(1,))
    ratio = hm.amplitude[:, :, 0] / hp.amplitude[:, :, 0]
    view = {"f_Hz": hm.f_Hz.tolist(),
            "gain_error_dB": np.median(20 * np.log10(np.abs(ratio)), axis=0).tolist(),
            "phase_error_deg": np.degrees(np.angle(np.median(ratio / np.abs(ratio), axis=0))
                                          ).tolist()}
    return Footprint(f_Hz=tuple(view["f_Hz"]), gain_error_dB=tuple(view["gain_error_dB"]),
                     phase_error_deg=tuple(view["phase_error_deg"]), shape=phase_shape(view))


@dataclass
class Signatures:
    """What each effect would leave in the nominal model's held-out residual.

    Attributes
    ----------
    transfer_function : PhaseShape
        :func:`phase_shape` of the nominal model's gain and phase errors.
    effect_footprint : Footprint or None
        :func:`effect_footprint` of the winner (None: no winner).
    gain_vs_stimulation : dict
        ``slope_per_100s`` and ``correlation`` of the trials' gain with cumulative
        stimulation (fatigue).
    harmonics : dict
        Median residual 2f and 3f harmonics and the non-harmonic 1.5f reference, % of the
        fundamental (recruitment).
    low_frequency : dict
        The residual power's share below the chirp band, that of white noise and their
        ratio (baseline drift).
    """

    transfer_function: PhaseShape
    effect_footprint: Footprint | None
    gain_vs_stimulation: dict
    harmonics: dict
    low_frequency: dict

    @property
    def phase(self) -> PhaseShape:
        """The transfer-function view an effect is judged on: the winner's footprint when
        there is one, else the nominal model's."""
        if self.effect_footprint is not None:
            return self.effect_footprint.shape
        return self.transfer_function

    def to_dict(self) -> dict:
        """The report's form (``gap_report.json``, ``evidence.signatures``)."""
        out = dict(vars(self))
        out["transfer_function"] = self.transfer_function.to_dict()
        out["effect_footprint"] = (self.effect_footprint.to_dict()
                                   if self.effect_footprint is not None else None)
        return out


def signatures(diag: Diagnosis, loc: Localization) -> Signatures:
    """Every signature, from the nominal model's held-out residual (and the winner's
    footprint)."""
    fn = loc.frequency["nominal"]
    h = fn.residual_harmonic_pct
    gs = loc.gain_vs_stimulation
    sp = loc.spectrum["nominal"]
    return Signatures(
        transfer_function=phase_shape(fn),
        effect_footprint=effect_footprint(diag),
        gain_vs_stimulation={"slope_per_100s": gs["slope_per_100s"],
                             "correlation": gs["correlation"]},
        harmonics={"median_2f_pct": float(np.median(h["2f"])),
                   "median_3f_pct": float(np.median(h["3f"])),
                   "median_1.5f_noise_reference_pct": float(np.median(h["1.5f"]))},
        low_frequency={"share_below_chirp": sp.low_share,
                       "share_if_white": sp.low_share_if_white,
                       "excess": sp.low_excess})


def explain(diag: Diagnosis, sig: Signatures) -> list[str]:
    """Plain-language lines: the verdict, the signature seen, how rivals were ruled out."""
    lines = []
    nom = diag.nominal
    final = diag.best_pair or diag.best
    skipped = getattr(diag, "candidates_skipped", None)
    if final is None and skipped:
        lines.append(f"none: {skipped}; the nominal model is as good as the data allow "
                     f"(held-out NRMSE {nom.heldout_nrmse_pct:.3g} %; repeat-to-repeat noise "
                     f"floor {diag.noise_floor_nrmse_pct:.3g} %).")
        return lines
    if final is None:
        lines.append(
            f"none: no candidate cut the held-out NRMSE ({nom.heldout_nrmse_pct:.3g} %; "
            f"repeat-to-repeat noise floor {diag.noise_floor_nrmse_pct:.3g} %) by "
            f"{diag.settings.min_shrink_pct:g} % or more with dIC < "
            f"-{diag.settings.ic_margin:g}"
            + ("; the nominal model is as good as the data allow."
               if diag.assessment.get("verdict", "none") == "none" else
               f"; {diag.assessment.get('label')} has the best evidence but trial-to-trial "
               "scatter hides it from the held-out test (likely, not separable)."
               if diag.assessment.get("verdict") == "likely" else
               "; what the nominal model misses is not one of the candidate effects."))
        return lines
    lines.append(f"{final.label}: held-out NRMSE {nom.heldout_nrmse_pct:.3g} % -> "
                 f"{final.heldout_nrmse_pct:.3g} % ({final.shrink_pct:.0f} % smaller), dIC "
                 f"{final.delta_ic:.0f} (N_eff = {final.nu:.2f} N).")
    e = diag.best_effect
    if e in FORMS:
        lines.append(FORMS[e].signature(sig))
    by = {r.candidate.effect: r for r in diag.candidates}
    for a, b in confusable():
        if e not in (a, b) or a not in by or b not in by:
            continue
        other = by[b if e is a else a]
        lines.append(
            f"{e.value} vs {other.label}: held-out {by[e].heldout_nrmse_pct:.3g} % vs "
            f"{other.heldout_nrmse_pct:.3g} %, dIC {by[e].delta_ic:.0f} vs "
            f"{other.delta_ic:.0f}; {other.label} explains less of the gap"
            + (" (it is also supported on its own: the two are partly confusable here)"
               if other.supported else "") + ".")
    return lines


def confusable_pairs(diag: Diagnosis, sig: Signatures) -> list[dict]:
    """For each confusable pair (:func:`confusable`): both candidates' scores, which one the
    data prefer, and what the effects' modules add (``FittedForm.pair_evidence``: the dead
    time's phase shape against an activation lag)."""
    by = {r.candidate.effect: r for r in diag.candidates}
    out = []
    for a, b in confusable():
        if a not in by or b not in by:
            continue
        ra, rb = by[a], by[b]
        pref = a if ra.heldout_nrmse_pct <= rb.heldout_nrmse_pct else b
        item = {"pair": [a.value, b.value],
                "heldout_nrmse_pct": [ra.heldout_nrmse_pct, rb.heldout_nrmse_pct],
                "delta_ic": [ra.delta_ic, rb.delta_ic],
                "preferred": pref.value if (ra.supported or rb.supported) else "neither"}
        for e, other in ((a, b), (b, a)):     # what the effects' modules add to the pair
            extra = FORMS[e].pair_evidence(other.value, sig) if e in FORMS else None
            item.update(extra or {})
        out.append(item)
    return out
