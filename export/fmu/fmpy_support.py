"""Running the FMU in FMPy (the reference Python FMI importer) as the twin is run.

The FMU's co-simulation is exact for inputs that move in straight lines over each step when
the importer sets their first derivatives (``simulate_fmu(..., set_input_derivatives=True)``).
Two details of FMPy 0.3.32 (``fmpy/simulation.py``) need care:

- at a sample time FMPy takes an input's derivative from the interval that *ends* there
  (``Input.interpolate`` finds the left index with ``searchsorted``): :func:`fmpy_input`
  places the table's times a hair (1e-9 of a period) early so that it takes the interval
  that *begins* there;
- ``Input.__init__`` allocates 9 derivative slots per type, so ``set_input_derivatives``
  fails ("Can only assign sequence of same size") unless a model has exactly 9 continuous
  Real inputs: :func:`fmpy_input_derivatives_fixed` gives it one slot per input.
"""

from __future__ import annotations

import contextlib

import numpy as np


def fmpy_input(rE, sE, fs_Hz: float, *, lead: float = 1e-9) -> np.ndarray:
    """FMPy's input table (structured array: time, rE, sE) for samples at ``fs_Hz``.

    Parameters
    ----------
    rE : array-like
        EAA ratio per sample.
    sE : float or array-like
        EAA sum, constant or per sample.
    fs_Hz : float
        Sampling rate.
    lead : float
        Fraction of a period by which the times are early (see the module's note).
    """
    r = np.asarray(rE, dtype=float)
    sig = np.zeros(len(r), dtype=[("time", float), ("rE", float), ("sE", float)])
    sig["time"] = np.arange(len(r)) / fs_Hz - lead / fs_Hz
    sig["rE"] = r
    sig["sE"] = np.broadcast_to(np.asarray(sE, dtype=float), r.shape)
    return sig


def fmpy_joint_input(inputs: dict, fs_Hz: float, *, lead: float = 1e-9) -> np.ndarray:
    """FMPy's input table for an FMU of several joints: ``{joint: (rE, sE)}`` gives the
    columns ``rE_<joint>``, ``sE_<joint>`` (as :func:`fmpy_input` for each joint; every
    joint's rE has the same number of samples).

    Examples
    --------
    >>> t = fmpy_joint_input({"knee": ([0.5, 0.6], 0.7), "ankle": ([0.5, 0.4], 0.3)}, 1000.0)
    >>> t.dtype.names, float(t["sE_ankle"][1])
    (('time', 'rE_knee', 'sE_knee', 'rE_ankle', 'sE_ankle'), 0.3)
    """
    n = {len(np.asarray(r, dtype=float)) for r, _ in inputs.values()}
    if len(n) != 1:
        raise ValueError(f"every joint's rE needs the same number of samples, got {sorted(n)}")
    length = n.pop()
    cols = [("time", float)] + [(f"{q}_{j}", float) for j in inputs for q in ("rE", "sE")]
    sig = np.zeros(length, dtype=cols)
    sig["time"] = np.arange(length) / fs_Hz - lead / fs_Hz
    for j, (rE, sE) in inputs.items():
        sig[f"rE_{j}"] = np.asarray(rE, dtype=float)
        sig[f"sE_{j}"] = np.broadcast_to(np.asarray(sE, dtype=float), (length,))
    return sig


@contextlib.contextmanager
def fmpy_input_derivatives_fixed():
    """Within the block, FMPy's ``Input`` has one derivative slot per input."""
    # FMPy is an optional dependency (extra 'test'); loaded only by whoever runs the FMU
    import fmpy.simulation as fsim

    orig = fsim.Input.__init__

    def init(self, *args, **kwargs):
        orig(self, *args, **kwargs)
        self.continuous = [c._replace(derivatives=(c.values._type_ * len(c.vrs))())
                           for c in self.continuous]

    fsim.Input.__init__ = init
    try:
        yield
    finally:
        fsim.Input.__init__ = orig


def on_output_grid(result, name: str, every: int = 1) -> np.ndarray:
    """A recorded output on the output grid. FMPy records both sides of an event at the
    same time (the FMU asks for a step event when an input changed, in model exchange);
    keep the value after it, then every ``every``-th point."""
    t = result["time"]
    keep = np.r_[t[1:] != t[:-1], True]
    return np.asarray(result[name][keep][::every])
