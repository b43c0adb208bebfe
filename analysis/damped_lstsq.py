"""The one damped least-squares solver of the analysis (Levenberg-Marquardt).

Both output-error fits use it: the per-sE second-order identification
(:mod:`nmsid.analysis.second_order`, two parameters, analytic projected Jacobian) and the gap
diagnosis's joint fits (:mod:`nmsid.analysis.gap.fit`, tens of parameters over millions of
residuals, so the Jacobian is never formed: the caller hands over the normal equations).
``scipy.optimize.least_squares`` would need the Jacobian itself (hundreds of MB for a gap
fit), hence this small solver on ``J^T J`` and ``J^T r``.

The step solves ``(H + mu D) s = -g`` with ``H = J^T J``, ``g = J^T r`` and Marquardt's
scaling ``D = diag(H)`` (Marquardt 1963; Nocedal & Wright 2006, sec. 10.3). A step that
does not lower the cost is refused and ``mu`` grows; an accepted one shrinks ``mu``.
Bounds: parameters at a bound that the step would push outward are held there (a small
active set), and the step is clipped into the box.

Examples
--------
>>> import numpy as np
>>> t = np.linspace(0, 1, 50)
>>> y = 2.0 * np.exp(-3.0 * t)
>>> def evaluate(x):
...     r = x[0] * np.exp(-x[1] * t) - y
...     return float(r @ r), r
>>> def normal(x, r):
...     J = np.column_stack([np.exp(-x[1] * t), -x[0] * t * np.exp(-x[1] * t)])
...     return J.T @ J, J.T @ r
>>> res = levenberg_marquardt(evaluate, normal, np.array([1.0, 1.0]))
>>> res.converged, np.round(res.x, 6).tolist()
(True, [2.0, 3.0])
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class Damping:
    """How ``mu`` starts and moves, and when the search stops.

    Attributes
    ----------
    start : float
        Initial ``mu``.
    up, down : float
        Factor on ``mu`` after a refused / an accepted step.
    floor, ceiling : float
        ``mu`` never falls below ``floor``; the search for a step gives up at ``ceiling``.
    step_tol : float
        Converged when the accepted step's largest component is below this.
    rel_tol : float
        Converged when the cost fell by less than ``rel_tol`` of the cost (``relative_to``:
        ``"before"`` or ``"after"`` the step) ...
    rel_step_tol : float
        ... and the step is below this (``inf``: the decrease alone decides).
    accept_equal : bool
        Accept a step that leaves the cost unchanged (``<=`` instead of ``<``).
    up_singular : float
        Factor on ``mu`` when the damped system is singular.
    zero_diag : float
        The scaling used for a parameter whose ``H`` diagonal is not positive.
    """

    start: float = 1e-3
    up: float = 10.0
    down: float = 10.0
    floor: float = 1e-12
    ceiling: float = 1e12
    step_tol: float = 1e-10
    rel_tol: float = 1e-9
    rel_step_tol: float = math.inf
    relative_to: str = "before"
    accept_equal: bool = False
    up_singular: float = 10.0
    zero_diag: float = 1.0


@dataclass
class DampedResult:
    """The minimiser's answer.

    Attributes
    ----------
    x : numpy.ndarray
        The parameters at the end.
    state : object
        What ``evaluate`` returned at ``x`` (the caller's residual, fit, ...).
    cost : float
        ``sum(r^2)`` at ``x``.
    converged : bool
    stalled : bool
        True when the search ended because no step lowered the cost.
    message : str
    iterations : int
    """

    x: np.ndarray
    state: Any
    cost: float
    converged: bool
    stalled: bool
    message: str
    iterations: int


def levenberg_marquardt(evaluate: Callable[[np.ndarray], tuple[float, Any]],
                        normal: Callable[[np.ndarray, Any], tuple[np.ndarray, np.ndarray]],
                        x0: np.ndarray, *, lo: np.ndarray | None = None,
                        hi: np.ndarray | None = None, max_iter: int = 30,
                        damping: Damping = Damping(),
                        stalled_converged: Callable[[np.ndarray, np.ndarray, float], bool]
                        | None = None,
                        evaluated: tuple[float, Any] | None = None) -> DampedResult:
    """Minimise ``sum(r(x)^2)`` from ``x0``.

    Parameters
    ----------
    evaluate : callable
        ``x -> (cost, state)``; a non-finite cost refuses the point.
    normal : callable
        ``(x, state) -> (H, g)``: ``J^T J`` and ``J^T r`` at ``x`` (``J = dr/dx``).
    x0 : ndarray
    lo, hi : ndarray, optional
        Bounds (closed); the start is clipped into them.
    max_iter : int
        Accepted steps at most.
    damping : Damping
    stalled_converged : callable, optional
        ``(H, g, cost) -> bool``: whether a point where no step lowers the cost counts as
        a minimum (default: always).
    evaluated : (float, object), optional
        ``evaluate``'s answer at ``x0`` when the caller has it (or must compute it
        differently, e.g. a start outside bounds that refuse trial points).

    Returns
    -------
    DampedResult
    """
    x = np.array(x0, dtype=float)
    bounded = lo is not None and hi is not None
    if bounded:
        x = np.clip(x, lo, hi)
    cost, state = evaluated if evaluated is not None else evaluate(x)
    mu = damping.start
    it = 0
    for it in range(1, max_iter + 1):
        H, g = normal(x, state)
        d = np.diag(H).copy()
        d[~(d > 0)] = damping.zero_diag
        accepted = False
        step = np.zeros(x.size)
        while mu < damping.ceiling:
            trial = _step(H, g, d, mu, x, lo, hi)
            if trial is None:
                mu *= damping.up_singular
                continue
            step = trial
            x_new = np.clip(x + step, lo, hi) if bounded else x + step
            cost_new, state_new = evaluate(x_new)
            if np.isfinite(cost_new) and (cost_new < cost or
                                          damping.accept_equal and cost_new <= cost):
                accepted = True
                break
            mu *= damping.up
        if not accepted:
            ok = True if stalled_converged is None else stalled_converged(H, g, cost)
            return DampedResult(x, state, cost, ok, True,
                                "converged (at a minimum to rounding)" if ok else
                                "stopped: no step decreases the cost (flat or "
                                "ill-conditioned)", it)
        decrease = cost - cost_new
        ref = cost if damping.relative_to == "before" else cost_new
        x, cost, state = x_new, cost_new, state_new
        mu = max(mu / damping.down, damping.floor)
        big = float(np.max(np.abs(step))) if step.size else 0.0
        if big < damping.step_tol or (decrease <= damping.rel_tol * ref
                                      and big < damping.rel_step_tol):
            return DampedResult(x, state, cost, True, False,
                                f"converged after {it} iteration(s)", it)
    return DampedResult(x, state, cost, False, False, "iteration limit reached", it)


def _step(H, g, d, mu, x, lo, hi) -> np.ndarray | None:
    """The damped step, holding at a bound each parameter it would push outward; None if
    the system is singular."""
    free = np.ones(x.size, dtype=bool)
    step = np.zeros(x.size)
    A = H + mu * np.diag(d)
    for _ in range(3):
        try:
            sub = np.linalg.solve(A[np.ix_(free, free)], -g[free])
        except np.linalg.LinAlgError:
            return None
        step[:] = 0.0
        step[free] = sub
        if lo is None or hi is None:
            return step
        blocked = ((x <= lo + 1e-12) & (step < 0)) | ((x >= hi - 1e-12) & (step > 0))
        if not np.any(blocked & free):
            break
        free &= ~blocked
    return step
