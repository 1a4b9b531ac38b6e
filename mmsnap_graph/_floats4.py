"""Symmetric 4x4 algebra in plain Python floats (private helper module).

The one-frame solver of the stream (:mod:`mmsnap_graph.fusion.solvers.scalar`)
and the central tracker (:mod:`mmsnap_graph.tracking.central`) work on a
few 4x4 matrices per frame, where numpy's per-call cost would be most of the
time. A matrix is given row-major as 16 floats; a Cholesky factor as the
tuple ``(l00, l10, l11, l20, l21, l22, l30, l31, l32, l33)``.
"""

from __future__ import annotations

import math

__all__ = ["cholesky_4x4", "forward_4x4", "cholesky_solve_4x4", "cholesky_inverse_4x4"]


def cholesky_4x4(a, rtol: float = 1e-14) -> tuple[float, ...] | None:
    """Lower Cholesky factor of the symmetric 4x4 ``a`` (row-major, 16
    floats), unrolled; None when it is not positive definite: a pivot not
    above ``rtol`` times its diagonal entry, or not finite (NaN too)."""
    a00, a11, a22, a33 = a[0], a[5], a[10], a[15]
    if not (a00 > 0.0 and a11 > 0.0 and a22 > 0.0 and a33 > 0.0):
        return None
    l00 = math.sqrt(a00)
    l10, l20, l30 = a[4] / l00, a[8] / l00, a[12] / l00
    d = a11 - l10 * l10
    if not d > rtol * a11:
        return None
    l11 = math.sqrt(d)
    l21 = (a[9] - l20 * l10) / l11
    l31 = (a[13] - l30 * l10) / l11
    d = a22 - l20 * l20 - l21 * l21
    if not d > rtol * a22:
        return None
    l22 = math.sqrt(d)
    l32 = (a[14] - l30 * l20 - l31 * l21) / l22
    d = a33 - l30 * l30 - l31 * l31 - l32 * l32
    if not (d > rtol * a33 and math.isfinite(d)):
        return None
    return l00, l10, l11, l20, l21, l22, l30, l31, l32, math.sqrt(d)


def forward_4x4(lo, b) -> tuple[float, float, float, float]:
    """``y`` with ``L y = b`` for the factor ``lo`` of :func:`cholesky_4x4`."""
    l00, l10, l11, l20, l21, l22, l30, l31, l32, l33 = lo
    y0 = b[0] / l00
    y1 = (b[1] - l10 * y0) / l11
    y2 = (b[2] - l20 * y0 - l21 * y1) / l22
    return y0, y1, y2, (b[3] - l30 * y0 - l31 * y1 - l32 * y2) / l33


def cholesky_solve_4x4(lo, b) -> tuple[float, float, float, float]:
    """``x`` with ``L L^T x = b`` for the factor ``lo`` of :func:`cholesky_4x4`."""
    l00, l10, l11, l20, l21, l22, l30, l31, l32, l33 = lo
    y0, y1, y2, y3 = forward_4x4(lo, b)
    x3 = y3 / l33
    x2 = (y2 - l32 * x3) / l22
    x1 = (y1 - l21 * x2 - l31 * x3) / l11
    return (y0 - l10 * x1 - l20 * x2 - l30 * x3) / l00, x1, x2, x3


def cholesky_inverse_4x4(lo) -> list[float]:
    """``(L L^T)^-1 = L^-T L^-1`` as 16 row-major floats, exactly symmetric."""
    l00, l10, l11, l20, l21, l22, l30, l31, l32, l33 = lo
    # M = L^-1 (lower triangular), column by column.
    m00, m11, m22, m33 = 1.0 / l00, 1.0 / l11, 1.0 / l22, 1.0 / l33
    m10 = -l10 * m00 * m11
    m21 = -l21 * m11 * m22
    m20 = -(l20 * m00 + l21 * m10) * m22
    m32 = -l32 * m22 * m33
    m31 = -(l31 * m11 + l32 * m21) * m33
    m30 = -(l30 * m00 + l31 * m10 + l32 * m20) * m33
    c01 = m10 * m11 + m20 * m21 + m30 * m31
    c02 = m20 * m22 + m30 * m32
    c12 = m21 * m22 + m31 * m32
    c03, c13, c23 = m30 * m33, m31 * m33, m32 * m33
    return [m00 * m00 + m10 * m10 + m20 * m20 + m30 * m30, c01, c02, c03,
            c01, m11 * m11 + m21 * m21 + m31 * m31, c12, c13,
            c02, c12, m22 * m22 + m32 * m32, c23,
            c03, c13, c23, m33 * m33]
