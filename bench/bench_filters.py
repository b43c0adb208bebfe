"""The product's one recursive filter (issue 30, item 2): scipy's compiled ``lfilter`` and
``sosfilt`` kernels loaded by :mod:`nmsid.protocols.lti_kernels` without ``import
scipy.signal``, against the numpy fallbacks they replaced as the main path and against
``scipy.signal`` itself.

    python bench/bench_filters.py              # 7 repeats of each
    python bench/bench_filters.py --repeats 3

In one process, like for like on the same arrays: each figure is the median CPU time
(``time.process_time``: user + sys of this process, so a loaded machine stretches it less
than wall time) of ``--repeats`` calls, with its ratio against the fairest baseline:

* ``lfilter`` on an identification-sized batch (3 trials x 2000 samples, 2nd order) and a
  gap-sized one (45 trials x 30000 samples, 3rd order): the kernel against the numpy block
  scan (the fallback, forced) and against ``scipy.signal.lfilter`` (imported last);
* ``sosfiltfilt`` (4th-order Butterworth, QC's and preprocessing's) on the gap-sized batch,
  also against the sections one after the other through the compiled ``lfilter`` (the
  main path before scipy's ``_sosfilt`` was loaded too);
* ``lfilter_history``, the simulator's filter, over a 30000-sample trial in 100 ms chunks
  (200 samples, a new start from the past inputs and outputs each chunk);
* accuracy: a slow 3rd-order cascade at 2 kHz (poles ``|1 - p| ~ 1e-3``, a slow muscle
  with its activation lag), 30000 samples of a unit step, each path's largest error
  relative to ``scipy.signal.lfilter``.

Targets: the kernel bit-identical to ``scipy.signal.lfilter`` (error 0), ``sosfiltfilt``
bit-identical to ``scipy.signal.sosfiltfilt`` on the same sections, and not slower than the
numpy fallback it replaces on any of these calls.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
for _p in (ROOT, HERE):                          # nmsid; bench/ (cpu_time)
    if str(_p) not in sys.path:
        sys.path.insert(0, str(_p))

from cpu_time import cpu_median  # noqa: E402
from nmsid.analysis import signal_kernels as sk  # noqa: E402
from nmsid.protocols import lti_kernels as lti  # noqa: E402




class _Fallback:
    """Within the block: the numpy fallbacks, as if scipy's kernel could not be loaded."""

    def __enter__(self):
        self.saved = (lti._kernel, lti.source, lti._sos_kernel, lti.sos_source)
        lti._kernel, lti.source = None, "unavailable"
        lti._sos_kernel, lti.sos_source = None, "unavailable"

    def __exit__(self, *exc):
        lti._kernel, lti.source, lti._sos_kernel, lti.sos_source = self.saved


class _Sections:
    """Within the block: ``sosfilt``'s kernel hidden, so the sections run one after the
    other through the compiled ``lfilter`` (the main path before ``_sosfilt`` was loaded)."""

    def __enter__(self):
        self.saved = (lti._sos_kernel, lti.sos_source)
        lti._sos_kernel, lti.sos_source = None, "unavailable"

    def __exit__(self, *exc):
        lti._sos_kernel, lti.sos_source = self.saved


def _line(name: str, ours: float, base: float, base_name: str) -> None:
    ratio = base / ours if ours > 0 else float("inf")
    verdict = "" if base_name.startswith("scipy") or ratio >= 1.0 else " (missed: slower)"
    print(f"  {name:<44} {ours * 1e3:8.2f} ms CPU   {base_name} {base * 1e3:8.2f} ms: "
          f"{ratio:5.2f}x{verdict}")


def _history_chunks(b, a, x, chunk: int) -> np.ndarray:
    """The simulator's use: chunk by chunk, each continued from the last outputs."""
    out = []
    order = len(a) - 1
    xp, yp = np.zeros(order), np.zeros(order)
    for s in range(0, x.size, chunk):
        xc = x[s:s + chunk]
        yc = lti.lfilter_history(b, a, xc, xp, yp)
        xp, yp = xc[::-1][:order], yc[::-1][:order]
        out.append(yc)
    return np.concatenate(out)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args(argv)
    r = args.repeats
    rng = np.random.default_rng(1)
    assert lti.kernel_available(), "scipy's compiled kernel could not be loaded here"
    from nmsid.sim_backends.filters import dynamics_zoh
    b2, a2 = dynamics_zoh(12.0, 0.7, 0.0, 2000.0)
    b3, a3 = dynamics_zoh(4.0, 0.9, 0.04, 2000.0)
    small = rng.uniform(0, 1, (3, 2000))
    large = rng.uniform(0, 1, (45, 30000))
    trial = rng.uniform(0, 1, 30000)
    sos = sk.butter(4, 20.0, fs=2000.0)

    cases = {
        "lfilter, 3 x 2000, 2nd order": lambda: sk.lfilter(b2, a2, small),
        "lfilter, 45 x 30000, 3rd order": lambda: sk.lfilter(b3, a3, large),
        "sosfiltfilt, 45 x 30000, Butterworth 4": lambda: sk.sosfiltfilt(sos, large),
        "lfilter_history, 30000 in 200-sample chunks": lambda: _history_chunks(b3, a3, trial,
                                                                                200),
    }
    kernel = {k: cpu_median(fn, r) for k, fn in cases.items()}
    with _Fallback():
        numpy_s = {k: cpu_median(fn, r) for k, fn in cases.items()}
    import scipy.signal as ss   # last: its import is what the kernel loader avoids
    scipy_cases = {
        "lfilter, 3 x 2000, 2nd order": lambda: ss.lfilter(b2, a2, small),
        "lfilter, 45 x 30000, 3rd order": lambda: ss.lfilter(b3, a3, large),
        "sosfiltfilt, 45 x 30000, Butterworth 4": lambda: ss.sosfiltfilt(sos, large),
    }
    scipy_s = {k: cpu_median(fn, r) for k, fn in scipy_cases.items()}

    assert lti.sos_kernel_available(), "scipy's compiled _sosfilt could not be loaded here"
    print(f"one filter path: kernel source = {lti.source!r}, sosfilt kernel "
          f"{lti.sos_source!r}; median CPU of {r} calls")
    print("against the numpy fallback it replaced (same process, same arrays):")
    for k in cases:
        _line(k, kernel[k], numpy_s[k], "numpy")
    with _Sections():
        sections_s = cpu_median(cases["sosfiltfilt, 45 x 30000, Butterworth 4"], r)
    print("against the sections one by one through the compiled lfilter (the path before):")
    _line("sosfiltfilt, 45 x 30000, Butterworth 4", kernel["sosfiltfilt, 45 x 30000, "
          "Butterworth 4"], sections_s, "lfilter x sections")
    print("against scipy.signal (sosfiltfilt: scipy's own compiled sosfilt):")
    for k in scipy_cases:
        _line(k, kernel[k], scipy_s[k], "scipy.signal")

    p = np.array([0.999, 0.9985, 0.998])
    b = np.array([np.prod(1 - p)])
    a = np.poly(p)
    step = np.ones(30000)
    ref = ss.lfilter(b, a, step)
    scale = float(np.max(np.abs(ref)))
    err_kernel = float(np.max(np.abs(sk.lfilter(b, a, step) - ref))) / scale
    with _Fallback():
        err_numpy = float(np.max(np.abs(sk.lfilter(b, a, step) - ref))) / scale
    print("accuracy, slow 3rd-order cascade at 2 kHz, 30000-sample step, max |error| / max|y| "
          "against scipy.signal.lfilter:")
    print(f"  kernel {err_kernel:.1e} ({'met' if err_kernel == 0 else 'missed'}: "
          f"bit-identical), numpy block scan (fallback) {err_numpy:.1e}")
    same = np.array_equal(sk.sosfiltfilt(sos, large), ss.sosfiltfilt(sos, large))
    print(f"  sosfiltfilt, 45 x 30000, against scipy.signal.sosfiltfilt on the same sections: "
          f"{'bit-identical (met)' if same else 'differs (missed)'}")
    hist = _history_chunks(b3, a3, trial, 200)
    y = np.zeros(3)
    zi = ss.lfiltic(b3, a3, y, np.zeros(3))
    ref_h, _ = ss.lfilter(b3, a3, trial, zi=zi)
    print(f"  lfilter_history in chunks vs scipy.signal.lfilter in one call: max |error| / "
          f"max|y| {float(np.max(np.abs(hist - ref_h)) / np.max(np.abs(ref_h))):.1e}")


if __name__ == "__main__":
    main()
