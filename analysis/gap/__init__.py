"""The sim-to-real gap diagnosis (``nmsid gap``).

Three questions for recorded sessions: *where* does the simulation (the nominal twin, a
second-order model per sE) miss, *which* unmodelled effect explains the miss, and *how
far* does the miss shrink on held-out trials once that effect is added.

Modules, each with one job:

- :mod:`~nmsid.analysis.gap.data`: session files -> pre-processed arrays (:class:`GapData`),
  through identification's signal path (:mod:`nmsid.analysis.preprocess`,
  :mod:`nmsid.analysis.discretize`, :mod:`nmsid.analysis.input_timing`);
- :mod:`~nmsid.analysis.gap.models`: the nominal model and the six candidate augmentations;
- :mod:`~nmsid.analysis.gap.fit`: joint output-error fit (variable projection, grouped LM);
- :mod:`~nmsid.analysis.gap.crossval`: folds by repeat;
- :mod:`~nmsid.analysis.gap.diagnose`: scoring, the decision; :mod:`~nmsid.analysis.gap.samples`:
  effective samples;
- :mod:`~nmsid.analysis.gap.verdict`: none / effect / pair / unexplained, the remaining gap
  beyond noise and where it lies;
- :mod:`~nmsid.analysis.gap.localize`, :mod:`~nmsid.analysis.gap.harmonics`: where the gap lies;
- :mod:`~nmsid.analysis.gap.evidence`: the signatures and confusable pairs;
- :mod:`~nmsid.analysis.gap.twin_out`, :mod:`~nmsid.analysis.gap.report`,
  :mod:`~nmsid.analysis.gap.plots`: outputs;
- :mod:`~nmsid.analysis.gap.api`: :func:`run_gap`, the whole job in one call.

Examples
--------
>>> from nmsid.analysis.gap import Effect
>>> Effect("dead_time").value
'dead_time'
"""

from nmsid.protocols.effects import CANDIDATES, Effect

__all__ = ["Effect", "CANDIDATES", "run_gap", "diagnose", "load_session", "GapSettings"]


def __getattr__(name):
    # lazy re-exports: `from nmsid.analysis.gap import Effect` (the effect names only) must
    # not load the whole fitting stack and scipy.signal with it
    if name == "run_gap":
        from nmsid.analysis.gap.api import run_gap  # lazy, see above
        return run_gap
    if name in ("diagnose", "GapSettings"):
        from nmsid.analysis.gap import diagnose as m  # lazy, see above
        return getattr(m, name)
    if name == "load_session":
        from nmsid.analysis.gap.data import load_session  # lazy, see above
        return load_session
    raise AttributeError(name)
