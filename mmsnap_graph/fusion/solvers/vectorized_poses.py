"""Calibration-aware covariance by linear propagation (docs/CONVENTIONS.md,
"Calibration-aware fusion"); numpy only, vectorized over frames.

The one-shot estimate ``x(p)`` of a frame depends on the node poses ``p`` it
was computed with. When the poses come from a calibration with covariances
``Sigma_p`` (Pose2 body tangent, per node), the first-order error of the
estimate is ``dx = A dp`` with

.. math::

    A = -(J_x^T W J_x + \\Lambda_0)^{-1} J_x^T W J_p = -P_x J_x^T W J_p,

``J_x`` and ``J_p`` the measurement Jacobians with respect to the state and
to the pose retraction (:func:`factors.models.measurement_model_pose`), ``W``
the measurement information (each node's own sigmas, times its kernel weight
for a robust fit), ``Lambda_0`` the prior's information and ``P_x`` the
Laplace covariance with the poses taken as exact. Pose errors are independent
of the measurement noise, so

.. math::

    P = P_x + A \\Sigma_p A^T = P_x + P_x \\Big(\\sum_i B_i \\Sigma_{p,i} B_i^T\\Big) P_x,
    \\qquad B_i = J_{x,i}^T W_i J_{p,i},

the sum over the observed nodes with an uncertain pose. The GTSAM twin is
:mod:`mmsnap_graph.fusion.solvers.gtsam_poses`.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from factors.models import measurement_model_pose

__all__ = ["pose_information_term", "propagate_pose_covariance"]


def pose_information_term(
    state: NDArray,
    poses: NDArray,
    observed: NDArray,
    inv_sigma: NDArray,
    pose_cov: NDArray,
    weights: NDArray | None = None,
) -> NDArray:
    """``M = sum_i B_i Sigma_{p,i} B_i^T`` (F, 4, 4), ``B_i = J_x,i^T W_i J_p,i``.

    state : (F, 4); poses : (N, 3) or (F, N, 3); observed : (F, N) bool;
    inv_sigma : (N, 3) (or (3,)) inverse sigmas; pose_cov : (N, 3, 3), NaN
    for an exact pose; weights : (F, N) kernel weights or None (all 1).
    """
    n_frames = state.shape[0]
    inv_sigma = np.broadcast_to(inv_sigma, (pose_cov.shape[0], 3))
    term = np.zeros((n_frames, 4, 4))
    for n in range(pose_cov.shape[0]):
        if np.isnan(pose_cov[n]).all():
            continue
        w = observed[:, n].astype(float)
        if weights is not None:
            w = w * weights[:, n]
        if not np.any(w > 0):
            continue
        _, j_pose, j_state = measurement_model_pose(poses[..., n, :], state)
        b = np.einsum("fki,k,fkj->fij", j_state, inv_sigma[n] ** 2, j_pose)  # (F, 4, 3)
        # An unobserved node adds nothing (even where its model is undefined).
        b = np.where(w[:, None, None] > 0, b * w[:, None, None], 0.0)
        term += b @ pose_cov[n] @ np.swapaxes(b, -1, -2)
    return term


def propagate_pose_covariance(
    covariance: NDArray,
    state: NDArray,
    poses: NDArray,
    observed: NDArray,
    inv_sigma: NDArray,
    pose_cov: NDArray,
    weights: NDArray | None = None,
) -> NDArray:
    """``P = P_x + P_x M P_x`` (F, 4, 4) with ``M`` = :func:`pose_information_term`.

    covariance : (F, 4, 4) the covariances with exact poses (``P_x``);
    the other arguments as :func:`pose_information_term`.
    """
    cov = np.asarray(covariance, dtype=float)
    out = cov + cov @ pose_information_term(state, poses, observed, inv_sigma, pose_cov,
                                            weights) @ cov
    return 0.5 * (out + np.swapaxes(out, -1, -2))
