"""The row-wise least squares of the fits (CholeskyQR2 with a Gram-Schmidt fallback)."""

import numpy as np

from nmsid.analysis import thin_lstsq
from nmsid.analysis.thin_lstsq import lstsq_rows, orthonormalise


def _check_factors(rows, q, r):
    assert np.allclose(q @ q.T, np.eye(len(rows)), atol=1e-12)
    assert np.allclose(r.T @ q, rows, rtol=0, atol=1e-10 * np.abs(rows).max())
    assert np.allclose(np.tril(r, -1), 0.0)


def test_well_conditioned_rows_take_the_cholesky_path(monkeypatch):
    rng = np.random.default_rng(0)
    rows = rng.standard_normal((5, 2000))
    rows[3] = 1.0
    called = []
    monkeypatch.setattr(thin_lstsq, "_mgs", lambda a: called.append(a) or (a, a))
    q, r = orthonormalise(rows)
    assert not called
    _check_factors(rows, q, r)


def test_dependent_rows_fall_back_to_gram_schmidt_with_a_zero_row():
    rng = np.random.default_rng(1)
    rows = rng.standard_normal((4, 500))
    rows[2] = 2.0 * rows[0] - rows[1]            # exactly dependent
    q, r = orthonormalise(rows)
    assert np.all(q[2] == 0.0) and r[2, 2] == 0.0
    assert np.allclose(r.T @ q, rows, atol=1e-10)


def test_ill_conditioned_rows_fall_back(monkeypatch):
    rng = np.random.default_rng(2)
    rows = rng.standard_normal((3, 800))
    rows[2] = rows[0] + 1e-9 * rows[1]           # condition ~1e9: beyond CholeskyQR2
    seen = []
    real = thin_lstsq._mgs
    monkeypatch.setattr(thin_lstsq, "_mgs", lambda a: seen.append(1) or real(a))
    q, r = orthonormalise(rows)
    assert seen
    assert np.allclose(r.T @ q, rows, atol=1e-9)


def test_lstsq_rows_matches_numpy():
    rng = np.random.default_rng(3)
    rows = rng.standard_normal((5, 1000))
    y = rng.standard_normal(1000)
    coef, _, _ = lstsq_rows(rows, y)
    want = np.linalg.lstsq(rows.T, y, rcond=None)[0]
    assert np.allclose(coef, want, rtol=1e-10, atol=1e-12)
