"""The sim-to-real gap diagnosis (``nmsid gap``).

Three questions for recorded sessions: *where* does the simulation (the nominal twin, a
second-order model per sE) miss, *which* unmodelled effect explains the miss, and *how
far* does the miss shrink on held-out trials once that effect is added.

Modules, each with one job:

- :mod:`~analysis.gap.data`: session files -> pre-processed arrays (:class:`GapData`),
  through identification's signal path (:mod:`analysis.preprocess`,
  :mod:`analysis.discretize`, :mod:`analysis.input_timing`);
- :mod:`~analysis.gap.models`: the nominal model and the six candidate augmentations;
- :mod:`~analysis.gap.fit`: joint output-error fit (variable projection, grouped LM);
- :mod:`~analysis.gap.crossval`: folds by repeat;
- :mod:`~analysis.gap.diagnose`: scoring, the decision; :mod:`~analysis.gap.samples`:
  effective samples;
- :mod:`~analysis.gap.verdict`: none / effect / pair / unexplained, the remaining gap
  beyond noise and where it lies;
- :mod:`~analysis.gap.localize`, :mod:`~analysis.gap.harmonics`: where the gap lies;
- :mod:`~analysis.gap.evidence`: the signatures and confusable pairs;
- :mod:`~analysis.gap.twin_out`, :mod:`~analysis.gap.report`, :mod:`~analysis.gap.plots`:
  outputs;
- :mod:`~analysis.gap.api`: :func:`run_gap`, the whole job in one call.

Examples
--------
>>> from analysis.gap import Effect
>>> Effect("dead_time").value
'dead_time'
"""

from analysis.gap.effects import CANDIDATES, Effect

__all__ = ["Effect", "CANDIDATES", "run_gap", "diagnose", "load_session", "GapSettings"]


def __getattr__(name):
    # lazy re-exports: `import analysis.gap.effects` (the sim and the twin writer need only
    # the effect names) must not load the whole fitting stack and scipy.signal with it
    if name == "run_gap":
        from analysis.gap.api import run_gap  # lazy, see above
        return run_gap
    if name in ("diagnose", "GapSettings"):
        from analysis.gap import diagnose as m  # lazy, see above
        return getattr(m, name)
    if name == "load_session":
        from analysis.gap.data import load_session  # lazy, see above
        return load_session
    raise AttributeError(name)
