"""The velocity degeneracy indicator of one-shot fusion (no GTSAM):
:func:`velocity_degeneracy`, the condition number of the lines of sight
(``FusionSolution.degeneracy``), and :func:`condition_2x2`. Re-exported by
:mod:`mmsnap_graph.fusion.problem`.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["condition_2x2", "velocity_degeneracy"]


def condition_2x2(a11: float, a12: float, a22: float) -> float:
    """Condition number of the symmetric PSD matrix ``[[a11, a12], [a12, a22]]``
    (>= 1; inf when singular), in plain floats."""
    half_tr = 0.5 * (a11 + a22)
    disc = math.sqrt(0.25 * (a11 - a22) ** 2 + a12 * a12)
    hi = half_tr + disc
    lo = half_tr - disc
    if not hi > 0.0 or lo <= hi * 1e-15:
        return math.inf
    return hi / lo


def velocity_degeneracy(
    state: ArrayLike, node_poses: ArrayLike, observed: ArrayLike | None = None
) -> NDArray | float:
    """Condition number of ``sum_i u_i u_i^T`` over the observed nodes' lines
    of sight at ``state`` (>= 1; ``inf`` when singular: parallel lines of sight,
    a single node); see ``FusionSolution.degeneracy``. No validation.

    state : (F, 4) or (4,); node_poses : (N, 3) or (F, N, 3);
    observed : (F, N) or (N,) bool, or None (all observed).
    Returns (F,), or a float for a single (4,) state.
    """
    state = np.asarray(state, dtype=float)
    single = state.ndim == 1
    if single:
        state = state[None]
        if observed is not None:
            observed = np.asarray(observed, dtype=bool)[None]
    poses = np.asarray(node_poses, dtype=float)
    d = state[:, None, :2] - poses[..., :2]
    r2 = np.sum(d * d, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        w = 1.0 / r2
        if observed is not None:
            w = np.where(np.asarray(observed, dtype=bool), w, 0.0)
    a11 = np.sum(w * d[..., 0] ** 2, axis=1)
    a12 = np.sum(w * d[..., 0] * d[..., 1], axis=1)
    a22 = np.sum(w * d[..., 1] ** 2, axis=1)
    half_tr = 0.5 * (a11 + a22)
    disc = np.sqrt(0.25 * (a11 - a22) ** 2 + a12 * a12)
    hi = half_tr + disc
    lo = half_tr - disc
    with np.errstate(invalid="ignore", divide="ignore"):
        cond = hi / lo
    singular = ~(hi > 0) | (lo <= hi * 1e-15) | ~np.isfinite(cond)
    out = np.where(singular, np.inf, cond)
    return float(out[0]) if single else out
