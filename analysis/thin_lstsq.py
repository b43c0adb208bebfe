"""Least squares for a few long signals, fast on a small shared machine.

The fitter solves many small problems: 2000-20000 samples, 2-7 regressors. LAPACK's
``lstsq``/``qr`` on such tall matrices hand them to a threaded BLAS that, on a 2-core
machine shared with other processes, can be 10-100x slower than the arithmetic needs.
Here the regressors are the *rows* of a C-contiguous array; the only large operation is
the short-and-wide product ``rows @ other.T`` (fast on every BLAS), and the factorisation
is CholeskyQR2 (Fukaya et al. 2014: Cholesky QR applied twice, as accurate as Householder
QR for condition numbers up to ~1e8), with modified Gram-Schmidt twice as the fallback for
(nearly) dependent rows.
"""

from __future__ import annotations

import math

import numpy as np

#: OpenBLAS runs ``ddot`` multithreaded above 10000 elements; longer dots use numpy's
#: own reduction instead (slower when the machine is idle, never 100x slower when busy).
_BLAS_DOT_MAX = 8192


def dot(a: np.ndarray, b: np.ndarray) -> float:
    """Inner product of two 1-D arrays without multithreaded BLAS."""
    if a.shape[0] <= _BLAS_DOT_MAX:
        return float(a @ b)
    return float(np.multiply(a, b).sum())


def _mgs(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Modified Gram-Schmidt, twice ("twice is enough"); zero rows for dependent ones."""
    m, _ = rows.shape
    q = np.array(rows, dtype=float, order="C", copy=True)
    r = np.zeros((m, m))
    norms = np.array([np.sqrt(dot(row, row)) for row in rows])
    for k in range(m):
        for _ in range(2):
            for j in range(k):
                c = dot(q[j], q[k])
                r[j, k] += c
                q[k] -= c * q[j]
        nk = float(np.sqrt(dot(q[k], q[k])))
        if nk <= 1e-13 * max(norms[k], 1e-300):
            q[k] = 0.0
            r[k, k] = 0.0
        else:
            q[k] /= nk
            r[k, k] = nk
    return q, r


def orthonormalise(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """QR of the transposed rows: ``rows.T = Q.T @ R`` with orthonormal rows of Q.

    Parameters
    ----------
    rows : ndarray (m, n)
        m regressors of n samples each (m small).

    Returns
    -------
    q : ndarray (m, n)
        Orthonormal rows spanning the same space (a zero row where a regressor is
        linearly dependent on the previous ones).
    r : ndarray (m, m)
        Upper triangular, ``rows[k] = sum_j r[j, k] q[j]``.
    """
    a = np.ascontiguousarray(rows, dtype=float)
    try:
        # (m x m) inverses times the wide matrix: LAPACK's solve with n right-hand sides
        # would go through a threaded triangular solve
        l1 = np.linalg.cholesky(a @ a.T)
        q1 = np.linalg.inv(l1) @ a
        l2 = np.linalg.cholesky(q1 @ q1.T)
        q = np.linalg.inv(l2) @ q1
        r = (l1 @ l2).T
        diag = np.abs(np.diagonal(r))
        # a finite sum means finite entries (inf and nan propagate); only a sum that
        # overflowed needs the entries themselves
        if (math.isfinite(float(q.sum())) or bool(np.isfinite(q).all())) and \
                float(diag.min()) > 1e-7 * float(diag.max()):
            return q, r
    except np.linalg.LinAlgError:
        pass
    return _mgs(a)


def solve_triangular_upper(r: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Back substitution; a zero pivot gives a zero coefficient (dependent regressor)."""
    m = len(b)
    x = np.zeros(m)
    for i in range(m - 1, -1, -1):
        if r[i, i] == 0.0:
            continue
        x[i] = (b[i] - r[i, i + 1:] @ x[i + 1:]) / r[i, i]
    return x


def lstsq_rows(rows: np.ndarray, y: np.ndarray):
    """Least-squares coefficients c minimising ||y - rows.T c||.

    Returns
    -------
    coef : ndarray (m,)
    q, r : the factors of :func:`orthonormalise` (for projections and covariances)
    """
    q, r = orthonormalise(rows)
    return solve_triangular_upper(r, q @ y), q, r


def gram(rows: np.ndarray) -> np.ndarray:
    """rows @ rows.T."""
    rows = np.ascontiguousarray(rows)
    return rows @ rows.T


def cross(rows_a: np.ndarray, rows_b: np.ndarray) -> np.ndarray:
    """rows_a @ rows_b.T."""
    return np.ascontiguousarray(rows_a) @ np.ascontiguousarray(rows_b).T
