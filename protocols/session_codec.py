"""How trial signals are encoded in a session file: compression choice, A/D counts.

Pure functions on numpy arrays (and HDF5 attribute setting); used by
:mod:`nmsid.protocols.session_writer` and :mod:`nmsid.protocols.session_reader`.
"""

from __future__ import annotations

import json
import zlib
from typing import Any

import numpy as np

from nmsid.protocols.session_model import MIN_SAVING, _h5py


def _set_attr(attrs, key: str, value: Any) -> None:
    if isinstance(value, str):
        attrs.create(key, value, dtype=_h5py().string_dtype("utf-8"))
    elif isinstance(value, (dict, list)):
        attrs.create(key, json.dumps(value), dtype=_h5py().string_dtype("utf-8"))
    else:
        attrs[key] = value


_PROBE_BLOCKS, _PROBE_SAMPLES = 3, 2048
""":func:`_deflates` judges a long column on this many blocks of this many samples
(start, middle, end): deflating a whole trial only to decide took as long as storing it."""


def _deflates(data: np.ndarray) -> bool:
    """True if shuffle + deflate saves at least :data:`MIN_SAVING` of ``data``, judged
    the way it is chunked (each column of a 2-D dataset on its own), on blocks spread
    through each long column (:data:`_PROBE_BLOCKS`)."""
    raw = np.asarray(data)
    columns = [raw] if raw.ndim == 1 else [raw[:, k] for k in range(raw.shape[1])]
    packed = probed = 0
    for col in columns:
        n = col.shape[0]
        if n > _PROBE_BLOCKS * _PROBE_SAMPLES:
            starts = np.linspace(0, n - _PROBE_SAMPLES, _PROBE_BLOCKS).astype(int)
            blocks = [col[k:k + _PROBE_SAMPLES] for k in starts]
        else:
            blocks = [col]
        for block in blocks:
            block = np.ascontiguousarray(block)
            shuffled = block.view(np.uint8).reshape(-1, block.dtype.itemsize).T.tobytes()
            packed += len(zlib.compress(shuffled, 1))
            probed += block.nbytes
    return packed <= (1.0 - MIN_SAVING) * probed


def counts_to_values(counts: np.ndarray, scale, offset) -> np.ndarray:
    """float64 ``offset + scale * counts`` (``scale``, ``offset``: scalars, or one per
    column of a 2-D dataset): how a reader turns a stored count dataset into values."""
    out = np.asarray(counts).astype(np.float64)
    out *= np.asarray(scale, dtype=np.float64)
    out += np.asarray(offset, dtype=np.float64)
    return out


def _same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    return a.shape == b.shape and np.array_equal(a.view(np.int64), b.view(np.int64))


_MAX_SUBSTEPS = 4096
"""A grid is found when its step is at least 1/4096 of the smallest gap between values."""


def _column_step(col: np.ndarray) -> float | None:
    """The step ``q`` with ``col == q * k`` bit for bit for integers ``k`` (|k| < 2**31),
    or None. Candidates: ``x / k`` of the largest samples and their neighbouring floats
    (``fl(q * k)`` is correctly rounded, so the true step is within an ulp or two)."""
    nz = np.unique(np.abs(col[col != 0.0]))
    if nz.size == 0:
        return None
    diffs = np.concatenate([nz[:1], np.diff(nz)])
    step0 = float(diffs.min())
    if not step0 > 0 or nz[-1] / step0 >= 2 ** 31:
        return None
    # the common case first (an A/D whose codes are dense): the smallest gap is the step.
    # Exactly what the search below tries first whenever this succeeds (then every gap is
    # a whole number of steps, so one sub-step passes its test): only faster.
    q = _exact_step_near(col, nz, step0)
    if q is not None:
        return q
    # sparse codes: the smallest gap may be several steps; the step divides every gap.
    # A gap between floats is off by up to ~2 ulps of its upper end, so the test that
    # ``m * gap / step0`` is whole allows for that error (and step0's own) times m.
    substeps = [1]
    pick = slice(None, None, max(1, diffs.size // 64))
    gaps, ups = diffs[pick][:64], nz[pick][:64]
    ratios = gaps / step0
    if ratios.max() * _MAX_SUBSTEPS < 2 ** 40:
        eps = np.finfo(float).eps
        err0 = 2 * eps * nz[int(np.argmin(diffs))]
        ratio_err = (2 * eps * ups + ratios * err0) / step0
        m = np.arange(1, _MAX_SUBSTEPS + 1)[:, None]
        ok = np.flatnonzero((np.abs(m * ratios - np.rint(m * ratios))
                             < 1e-4 + 2 * m * ratio_err).all(axis=1))
        if ok.size == 0:
            return None
        substeps = [int(k) + 1 for k in ok[:8]]
    for sub in substeps:
        q = _exact_step_near(col, nz, step0 / sub)
        if q is not None:
            return q
    return None


def _exact_step_near(col: np.ndarray, nz: np.ndarray, step0: float) -> float | None:
    """The float ``q`` within a few ulps of ``x / round(x / step0)`` (x: a large, middle
    and small sample) for which ``col == q * round(col / q)`` bit for bit, or None."""
    tried = set()
    for x in (nz[-1], nz[nz.size // 2], nz[0]):
        k = float(np.rint(x / step0))
        if k < 1:
            continue
        q = x / k
        for cand in (q, *np.nextafter(q, [np.inf, 0.0]),
                     *np.nextafter(np.nextafter(q, [np.inf, 0.0]), [np.inf, 0.0])):
            cand = float(cand)
            if cand in tried or not cand > 0:
                continue
            tried.add(cand)
            counts = np.rint(col / cand)
            if np.abs(counts).max() < 2 ** 31 and _same_bits(counts * cand, col):
                return cand
    return None


def _as_counts(values) -> tuple[np.ndarray, Any, Any] | None:
    """``(counts, scale, offset)`` if every sample of ``values`` (1-D, or 2-D column by
    column) is ``offset + scale * count`` bit for bit as :func:`counts_to_values`
    rebuilds it, with the counts as int8/int16/int32; else None.

    A/D readings (``code * LSB``, the simulated chain's wrench, a sync line at 0 / 5 V)
    pass; float noise does not. The writer detects grids through zero (``offset`` 0);
    readers honour any ``offset``.
    """
    arr = np.asarray(values, dtype=np.float64)
    if arr.size == 0 or arr.ndim not in (1, 2) or not np.isfinite(arr).all():
        return None
    cols = [arr] if arr.ndim == 1 else [arr[:, k] for k in range(arr.shape[1])]
    scales = []
    for col in cols:
        if not col.any():
            scales.append(1.0)
            continue
        q = _column_step(col)
        if q is None:
            return None
        scales.append(q)
    scale = np.array(scales) if arr.ndim == 2 else np.float64(scales[0])
    counts = np.rint(arr / scale)
    dtype = next(dt for dt in (np.int8, np.int16, np.int32)
                 if np.iinfo(dt).min <= counts.min() and counts.max() <= np.iinfo(dt).max)
    counts = counts.astype(dtype)
    offset = np.zeros_like(scale)
    if not _same_bits(counts_to_values(counts, scale, offset), arr):
        return None
    return counts, scale, offset


def _narrowest_exact(values) -> np.ndarray:
    """``values`` as float32 if every sample survives the round trip bit for bit (a
    measurement that was float32 or A/D counts to begin with), else as float64.

    Only the optional datasets (``wrench``, ``sync``) are narrowed; the contract fixes
    the required ones at float64.
    """
    arr = np.asarray(values)
    as64 = arr.astype(np.float64)
    as32 = as64.astype(np.float32)
    if np.array_equal(as32.astype(np.float64), as64, equal_nan=True):
        return as32
    return as64


