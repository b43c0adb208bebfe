"""Counted rates in the benchmarks' output: a Wilson 95 % interval and what it can show.

A rate counted over n sessions or trials is printed with its interval, and a target is
judged on the interval: "met" when the whole interval is on the right side, "point
estimate only" when the count meets it but cannot show it at 95 %, "missed" otherwise.

>>> rate(118, 120, ">=", 95.0)
'118/120 = 98.3 % (Wilson 95 % 94.1-99.5 %); target >= 95 %: point estimate only'
>>> rate(0, 1830, "<=", 2.0)
'0/1830 = 0.00 % (Wilson 95 % 0.00-0.21 %); target <= 2 %: met'
"""

from __future__ import annotations

import math


def wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """Wilson score interval of a proportion ``k / n``, percent (NaN for ``n == 0``)."""
    if n == 0:
        return float("nan"), float("nan")
    p = k / n
    den = 1 + z * z / n
    c = (p + z * z / (2 * n)) / den
    h = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return 100 * max(0.0, c - h), 100 * min(1.0, c + h)


def verdict(k: int, n: int, sense: str, target_pct: float) -> str:
    """"met", "point estimate only" or "missed" for the target ``sense target_pct``
    (``sense`` ">=" or "<=") on ``k`` of ``n``."""
    if sense not in (">=", "<="):
        raise ValueError(f"sense {sense!r}: give '>=' or '<='")
    if n == 0:
        return "missed"
    lo, hi = wilson(k, n)
    p = 100 * k / n
    if sense == ">=":
        return "met" if lo >= target_pct else "point estimate only" if p >= target_pct \
            else "missed"
    return "met" if hi <= target_pct else "point estimate only" if p <= target_pct \
        else "missed"


def rate(k: int, n: int, sense: str, target_pct: float) -> str:
    """``k/n = p % (Wilson 95 % lo-hi %); target sense T %: verdict``."""
    lo, hi = wilson(k, n)
    digits = 2 if max(hi, 100 * k / max(n, 1)) < 10 else 1
    return (f"{k}/{n} = {100 * k / max(n, 1):.{digits}f} % (Wilson 95 % {lo:.{digits}f}-"
            f"{hi:.{digits}f} %); target {sense} {target_pct:g} %: "
            f"{verdict(k, n, sense, target_pct)}")
