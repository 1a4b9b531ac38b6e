"""Batched small-matrix algebra (4x4 and smaller), written entry by entry over
a leading axis of frames so that numpy loops over frames in C: ``np.linalg``
on stacks of 4x4 matrices pays a per-matrix overhead that dominates at these
sizes. The batch fusion solver and track-level fusion share it.

"Structure of arrays" (SoA) layout: a stack ``(F, n, n)`` is held as
``(n, n, F)`` (:func:`to_soa`), so that every operation runs over a
contiguous array of frames.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "to_soa",
    "from_soa",
    "chol_soa",
    "solve_soa",
    "inverse_soa",
    "cholesky4",
    "cholesky4_solve",
    "cholesky4_inverse",
    "symmetrize",
]

# Relative pivot below which a matrix counts as singular: about the
# precision of a Cholesky factorization in double precision.
_PIVOT_RTOL = 1e-12


def to_soa(a: NDArray) -> NDArray:
    """(..., n, n) -> contiguous (n, n, ...): each entry a contiguous array."""
    return np.ascontiguousarray(np.moveaxis(a, (-2, -1), (0, 1)))


def from_soa(a_t: NDArray) -> NDArray:
    return np.ascontiguousarray(np.moveaxis(a_t, (0, 1), (-2, -1)))


def chol_soa(a_t: NDArray):
    """Cholesky of (n, n, ...) symmetric matrices; returns the factor as a
    list of lists of arrays (lower triangle) and ``ok``."""
    n = a_t.shape[0]
    ok = np.all(np.isfinite(a_t), axis=(0, 1))
    lo = [[None] * n for _ in range(n)]
    for j in range(n):
        d = a_t[j, j].copy()
        for k in range(j):
            d -= lo[j][k] ** 2
        # The pivot against the column's own diagonal: a column that the
        # previous ones explain to rounding is singular. (An ill-conditioned
        # but regular matrix passes, as in gtsam's Cholesky.)
        good = d > _PIVOT_RTOL * np.abs(a_t[j, j])
        good &= a_t[j, j] > 0
        ok &= good
        ljj = np.sqrt(np.where(good, d, 1.0))
        lo[j][j] = ljj
        inv = 1.0 / ljj
        for i in range(j + 1, n):
            v = a_t[i, j].copy()
            for k in range(j):
                v -= lo[i][k] * lo[j][k]
            v *= inv
            lo[i][j] = v
    return lo, ok


def solve_soa(lo, b_t: NDArray) -> NDArray:
    """Solve ``L L^T x = b`` with ``L`` from :func:`chol_soa`; b_t (n, ...)."""
    n = len(lo)
    y = [None] * n
    for i in range(n):
        v = b_t[i].copy()
        for k in range(i):
            v -= lo[i][k] * y[k]
        y[i] = v / lo[i][i]
    x = [None] * n
    for i in reversed(range(n)):
        v = y[i]
        for k in range(i + 1, n):
            v = v - lo[k][i] * x[k]
        x[i] = v / lo[i][i]
    return np.stack(x)


def inverse_soa(lo) -> NDArray:
    """``(L L^T)^-1`` as ``M^T M`` with ``M = L^-1``; (n, n, ...), exactly symmetric."""
    n = len(lo)
    m = [[None] * n for _ in range(n)]
    for i in range(n):
        m[i][i] = 1.0 / lo[i][i]
        for j in range(i):
            v = lo[i][j] * m[j][j]
            for k in range(j + 1, i):
                v = v + lo[i][k] * m[k][j]
            m[i][j] = -v * m[i][i]
    out = np.empty((n, n) + lo[0][0].shape)
    for i in range(n):
        for j in range(i + 1):
            v = m[i][i] * m[i][j]
            for k in range(i + 1, n):
                v = v + m[k][i] * m[k][j]
            out[i, j] = v
            out[j, i] = v
    return out


def cholesky4(a: ArrayLike) -> tuple[NDArray, NDArray]:
    """Lower Cholesky factors of a stack of symmetric matrices (4x4 in this
    module, any small n works).

    a : (..., n, n) float, symmetric (only the lower triangle is read).
    Returns ``L (..., n, n)`` with ``a = L L^T`` and ``ok (...,)`` bool, False
    where a pivot is not above ``1e-12`` times its column's diagonal entry,
    i.e. the matrix is not numerically positive definite. Where
    ``ok`` is False the factor holds finite placeholder values.
    """
    a_t = to_soa(np.asarray(a, dtype=float))
    lo, ok = chol_soa(a_t)
    n = a_t.shape[0]
    out = np.zeros(a_t.shape)
    for i in range(n):
        for j in range(i + 1):
            out[i, j] = lo[i][j]
    return from_soa(out), ok


def lower_lists(chol: ArrayLike):
    c_t = to_soa(np.asarray(chol, dtype=float))
    n = c_t.shape[0]
    return [[c_t[i, j] if j <= i else None for j in range(n)] for i in range(n)]


def cholesky4_solve(chol: ArrayLike, b: ArrayLike) -> NDArray:
    """Solve ``L L^T x = b`` for stacks: chol (..., n, n) lower, b (..., n)."""
    b = np.asarray(b, dtype=float)
    return np.moveaxis(solve_soa(lower_lists(chol), np.moveaxis(b, -1, 0)), 0, -1)


def cholesky4_inverse(chol: ArrayLike) -> NDArray:
    """``(L L^T)^-1`` for a stack of lower Cholesky factors (..., n, n),
    as ``M^T M`` with ``M = L^-1``; exactly symmetric."""
    return from_soa(inverse_soa(lower_lists(chol)))


# ----------------------------------------------------------------------------
# The solver
# ----------------------------------------------------------------------------




def symmetrize(p: NDArray) -> NDArray:
    """``(P + P^T) / 2`` over the last two axes: removes the rounding asymmetry
    of a covariance update."""
    return 0.5 * (p + np.swapaxes(p, -1, -2))
