"""Least squares for a few long signals, without multithreaded BLAS.

The fitter solves many small problems: 2000-20000 samples, 2-7 regressors. Dense LAPACK
(``lstsq``, ``qr``, ``A.T @ A``) hands such shapes to a threaded BLAS, which on a small
machine shared by other processes can be 10-100x slower than the arithmetic needs. Here
the regressors are the *rows* of a C-contiguous array and everything is one-dimensional
dot products: modified Gram-Schmidt with one re-orthogonalisation ("twice is enough",
Giraud et al. 2005), as accurate as Householder QR for these well-scaled problems.
"""

from __future__ import annotations

import numpy as np

#: OpenBLAS runs ``ddot`` multithreaded above 10000 elements; longer dots use numpy's
#: own reduction instead (slower when the machine is idle, never 100x slower when busy).
_BLAS_DOT_MAX = 8192


def dot(a: np.ndarray, b: np.ndarray) -> float:
    """Inner product of two 1-D arrays without multithreaded BLAS."""
    if a.shape[0] <= _BLAS_DOT_MAX:
        return float(a @ b)
    return float(np.multiply(a, b).sum())


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


def project_out(q: np.ndarray, x: np.ndarray) -> np.ndarray:
    """x minus its projection on the span of the orthonormal rows q."""
    out = np.array(x, dtype=float, copy=True)
    for row in q:
        out -= dot(row, out) * row
    return out


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
    qty = np.array([dot(row, y) for row in q])
    return solve_triangular_upper(r, qty), q, r


def gram(rows: np.ndarray) -> np.ndarray:
    """rows @ rows.T by one-dimensional dot products."""
    m = len(rows)
    g = np.empty((m, m))
    for i in range(m):
        for j in range(i, m):
            g[i, j] = g[j, i] = dot(rows[i], rows[j])
    return g


def cross(rows_a: np.ndarray, rows_b: np.ndarray) -> np.ndarray:
    """rows_a @ rows_b.T by one-dimensional dot products."""
    return np.array([[dot(a, b) for b in rows_b] for a in rows_a])
