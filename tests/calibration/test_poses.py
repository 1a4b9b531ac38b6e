"""Pose2 helpers of the calibration (mmsnap_graph.calibration.poses): the
tangent error against the SE(2) logarithm written out here and the numpy
exponential map of tests/_pose_aware.py."""

from __future__ import annotations

import numpy as np
import pytest

from mmsnap_graph.calibration.poses import pose_array, pose_tangent_error, to_pose2

from _pose_aware import retract


def _se2_log(truth, estimate):
    """``Log(truth^-1 estimate)``: the relative pose, then ``v = V(w)^-1 t``."""
    c, s = np.cos(truth[2]), np.sin(truth[2])
    d = np.asarray(estimate[:2]) - truth[:2]
    t = np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1]])
    w = (estimate[2] - truth[2] + np.pi) % (2 * np.pi) - np.pi
    if abs(w) < 1e-12:
        return np.array([t[0], t[1], w])
    v = np.array([[np.sin(w), -(1 - np.cos(w))], [1 - np.cos(w), np.sin(w)]]) / w
    return np.concatenate([np.linalg.solve(v, t), [w]])


@pytest.mark.parametrize("seed", range(6))
def test_tangent_error_is_the_se2_log_and_inverts_the_retraction(seed):
    rng = np.random.default_rng(seed)
    truth = np.array([*rng.uniform(-5, 5, 2), rng.uniform(-np.pi, np.pi)])
    xi = rng.normal(size=3) * [0.5, 0.5, 0.8]
    estimate = retract(truth, xi)
    np.testing.assert_allclose(pose_tangent_error(estimate, truth), xi, atol=1e-12)
    np.testing.assert_allclose(pose_tangent_error(estimate, truth), _se2_log(truth, estimate),
                               atol=1e-12)
    np.testing.assert_allclose(pose_tangent_error(truth, truth), 0.0, atol=0)


def test_the_heading_wraps_and_pose_round_trips():
    truth = np.array([1.0, 2.0, np.pi - 0.01])
    est = np.array([1.0, 2.0, -np.pi + 0.01])  # 0.02 rad on, across the +-pi cut
    np.testing.assert_allclose(pose_tangent_error(est, truth), [0.0, 0.0, 0.02], atol=1e-12)
    p = np.array([3.0, -1.5, 0.7])
    np.testing.assert_array_equal(pose_array(to_pose2(p)), p)
