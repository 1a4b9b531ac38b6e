"""Calibration-aware covariance of one frame with GTSAM (docs/CONVENTIONS.md,
"Calibration-aware fusion").

The node poses of one-shot fusion come from a calibration that reports their
covariances (its marginals, in the Pose2 body tangent). Here each uncertain
pose becomes a ``Pose2`` variable with a ``PriorFactorPose2`` at its
calibrated value and that covariance; its node's measurements use
:func:`factors.gtsam_factors.pose_measurement_factor` (pose and state), an
exact pose (the reference node) stays a constant
(:func:`factors.gtsam_factors.node_measurement_factor`). ``gtsam.Marginals``
of the target state in that graph, linearized at the fused estimate and the
calibrated poses, is the calibration-aware covariance: the estimate is not
moved, only its covariance grows.

The vectorized twin (linear propagation, no GTSAM) is
:mod:`mmsnap_graph.fusion.solvers.vectorized_poses`.
"""

from __future__ import annotations

from typing import Sequence

import gtsam
import numpy as np
from numpy.typing import NDArray

from factors.gtsam_factors import (
    measurement_noise,
    node_measurement_factor,
    pose_measurement_factor,
)

from ...data.noise import GaussianPrior, MeasurementNoise

__all__ = ["STATE_KEY", "pose_key", "build_pose_aware_graph", "pose_aware_covariance"]

#: Key of the target state in the calibration-aware graph (node ``i``'s pose: ``pose_key(i)``).
STATE_KEY = 0


def pose_key(node: int) -> int:
    """Key of node ``node``'s ``Pose2`` variable in the calibration-aware graph."""
    return 1 + int(node)


def build_pose_aware_graph(
    state: NDArray,
    poses: NDArray,
    z: NDArray,
    obs: NDArray | None,
    noise: Sequence[MeasurementNoise],
    prior: GaussianPrior | None,
    pose_cov: NDArray,
    kernel: tuple[str, float] | None = None,
) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
    """The graph and values of one validated frame with uncertain poses.

    state : (4,) the fused estimate; poses, z : (N, 3); obs : (N,) bool or
    None (all observed); noise : N :class:`MeasurementNoise`; pose_cov :
    (N, 3, 3), NaN for an exact pose; kernel : ``(name, k)`` of a robust fit
    (each node's factor then carries GTSAM's kernel, as in the fit).
    Only the observed nodes enter (an unobserved pose does not touch the state).
    """
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    values.insert(STATE_KEY, np.asarray(state, dtype=float))
    for i, (pose, zi, m) in enumerate(zip(poses, z, noise)):
        if obs is not None and not obs[i]:
            continue
        sigmas = np.array((m.range_m, m.omega_rad, m.doppler_mps))
        model = (measurement_noise(sigmas) if kernel is None
                 else measurement_noise(sigmas, kernel[0], kernel[1]))
        if np.isnan(pose_cov[i]).all():
            graph.add(node_measurement_factor(STATE_KEY, pose, zi, model))
            continue
        key = pose_key(i)
        value = gtsam.Pose2(float(pose[0]), float(pose[1]), float(pose[2]))
        values.insert(key, value)
        cov = 0.5 * (pose_cov[i] + pose_cov[i].T)
        graph.add(gtsam.PriorFactorPose2(key, value, gtsam.noiseModel.Gaussian.Covariance(cov)))
        graph.add(pose_measurement_factor(key, STATE_KEY, zi, model))
    if prior is not None:
        graph.add(gtsam.PriorFactorVector(STATE_KEY, np.asarray(prior.mean, dtype=float),
                                          gtsam.noiseModel.Diagonal.Sigmas(
                                              np.asarray(prior.sigmas, dtype=float))))
    return graph, values


def pose_aware_covariance(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> NDArray:
    """(4, 4): ``gtsam.Marginals`` of the state in a graph and values of
    :func:`build_pose_aware_graph`.

    Raises GTSAM's exception for an indeterminate system (the caller flags the frame).
    """
    cov = gtsam.Marginals(graph, values).marginalCovariance(STATE_KEY)
    return 0.5 * (cov + cov.T)
