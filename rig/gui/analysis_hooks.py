"""The GUI's two calls into ``analysis``: per-level identification and model selection.

Both run in worker threads of the panels. They adapt the analysis package's result
objects to what the panels draw, so the panels do not depend on its classes.
"""

from __future__ import annotations

from pathlib import Path

from rig.gui.results_panel import ModelFit, ParameterSelection, SelectionView


def identify_level(trials):
    """Identify one sE level from its trials (``analysis.identify.identify_level``).

    Returns the fitted second-order model (attributes ``Kp``, ``wn_rad_s``, ``zeta``,
    ``fit_pct``).

    Raises
    ------
    ValueError
        If nothing could be estimated; the message lists the analysis' reasons.
    """
    from analysis.identify import identify_level as _identify
    result = _identify(list(trials))
    if result.fit is None:
        raise ValueError("; ".join(result.problems) or "no parameters estimated")
    return result.fit


def select_models(session_path: Path) -> SelectionView:
    """Model selection of a finished session, as the results panel shows it."""
    raise ImportError("analysis model selection is not wired in yet", name="analysis")
