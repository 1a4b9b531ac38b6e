"""Small Pose2 helpers shared by the calibration modules."""

from __future__ import annotations

import gtsam
import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["to_pose2", "pose_array", "pose_tangent_error"]


def to_pose2(pose: ArrayLike) -> gtsam.Pose2:
    """``(x_m, y_m, phi_rad)`` -> ``gtsam.Pose2``."""
    p = np.asarray(pose, dtype=float)
    return gtsam.Pose2(float(p[0]), float(p[1]), float(p[2]))


def pose_array(pose: gtsam.Pose2) -> NDArray:
    """``gtsam.Pose2`` -> (3,) ``(x_m, y_m, phi_rad)``."""
    return np.array([pose.x(), pose.y(), pose.theta()])


def pose_tangent_error(estimate: ArrayLike, truth: ArrayLike) -> NDArray:
    """Error of an estimated pose in the truth's body-frame tangent,
    ``truth.localCoordinates(estimate)`` = ``Log(truth^-1 estimate)``, (3,)
    ``(dx_b, dy_b, dphi)``: the coordinates in which pose covariances are
    given, so ``e^T P^-1 e`` is the NEES. (Not
    :func:`mmsnap_graph.evaluation.pose_error`, which reports position
    and heading errors in the global frame.)"""
    return np.asarray(to_pose2(truth).localCoordinates(to_pose2(estimate)), dtype=float)
