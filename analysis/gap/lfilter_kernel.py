"""The gap fits' recursive filter: ``scipy.signal``'s compiled ``lfilter`` kernel, loaded
without ``import scipy.signal``.

The gap diagnosis runs its models hundreds to thousands of times, each a second- to
fourth-order difference equation per sE level over 2-3 trials of ~2000 samples: scipy's
compiled filter takes ~35 us a call there, the numpy block scan of
:mod:`nmsid.analysis.signal_kernels` two to three times as long. But ``import
scipy.signal`` costs 0.5 s of CPU (1-1.5 s on a loaded 2-core machine): it imports
``scipy.stats``, ``scipy.interpolate`` and ``scipy.optimize`` and re-documents every
function, for the one kernel used here. A template session's whole diagnosis, once its
candidates are settled (:func:`nmsid.analysis.gap.verdict.nominal_settles`), costs less.

So this module loads the extension module holding the kernel
(``scipy/signal/_sigtools``: ``_linear_filter(b, a, x, axis)``, the transposed direct
form II that ``scipy.signal.lfilter`` calls for ``len(a) > 1`` without initial
conditions) straight from its file, in ~0.2 ms. Results are bit-identical to
``scipy.signal.lfilter`` (the same compiled code; tests compare). The module name is
private to scipy: when it cannot be found or loaded (another scipy layout), or lacks
the function, :func:`lfilter` falls back to ``scipy.signal.lfilter`` and only start-up
time is lost. Nothing is registered in ``sys.modules``, so a later ``import
scipy.signal`` loads scipy as usual.
"""

from __future__ import annotations

import importlib.machinery
import importlib.util
import sys
from pathlib import Path
from typing import Callable

import numpy as np

_MODULE = "scipy.signal._sigtools"
_kernel: Callable | None = None
#: "compiled kernel" or "scipy.signal.lfilter" once the first call chose (for tests/bench).
source: str | None = None


def _load_kernel() -> Callable | None:
    """scipy's ``_linear_filter`` loaded from its extension file, or None."""
    import scipy  # the package's own start-up only (~5 ms; on Windows, its DLL paths)
    folder = Path(scipy.__file__).parent / "signal"
    for suffix in importlib.machinery.EXTENSION_SUFFIXES:
        path = folder / ("_sigtools" + suffix)
        if not path.is_file():
            continue
        had = _MODULE in sys.modules
        try:
            spec = importlib.util.spec_from_file_location(_MODULE, str(path))
            if spec is None or spec.loader is None:
                return None
            module = importlib.util.module_from_spec(spec)
            spec.loader.exec_module(module)
        except Exception:  # noqa: BLE001 - any failure: the public function instead
            return None
        finally:
            if not had:  # a single-phase module registers itself; scipy re-imports it
                sys.modules.pop(_MODULE, None)
        fn = getattr(module, "_linear_filter", None)
        return fn if callable(fn) else None
    return None


def _public(b, a, x, axis):
    import scipy.signal  # the fallback: the same kernel behind the public function
    return scipy.signal.lfilter(b, a, x, axis=axis)


def kernel() -> Callable:
    """``(b, a, x, axis) -> y``: the compiled kernel, or ``scipy.signal.lfilter``'s
    equivalent when the kernel cannot be loaded (chosen once per process)."""
    global _kernel, source
    if _kernel is None:
        fn = _load_kernel()
        if fn is not None:
            _kernel, source = fn, "compiled kernel"
        else:
            _kernel, source = _public, "scipy.signal.lfilter"
    return _kernel


def lfilter(b: np.ndarray, a: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``scipy.signal.lfilter(b, a, x, axis=-1)`` for float64 data, zero initial state.

    Parameters
    ----------
    b, a : (nb,), (na,) ndarray
        Numerator and denominator (``len(a) >= 2``, ``a[0] != 0``; scipy normalises by
        ``a[0]``).
    x : (..., n) ndarray
        Filtered along the last axis.

    Returns
    -------
    ndarray
        Same shape as ``x``.

    Examples
    --------
    >>> import numpy as np
    >>> np.round(lfilter(np.array([0.5]), np.array([1.0, -0.5]), np.ones(4)), 4).tolist()
    [0.5, 0.75, 0.875, 0.9375]
    """
    b = np.asarray(b, dtype=float)
    a = np.asarray(a, dtype=float)
    if a.ndim != 1 or b.ndim != 1 or a.size < 2 or b.size < 1 or a[0] == 0:
        raise ValueError(f"lfilter: b and a must be 1-D with len(a) >= 2 and a[0] != 0 "
                         f"(b.shape={b.shape}, a.shape={a.shape})")
    return kernel()(b, a, np.asarray(x, dtype=float), -1)
