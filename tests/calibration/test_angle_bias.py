"""A radar's angle bias (mmsnap_graph.calibration.angle_bias): the
self-calibration takes it as heading, and the mounting covariance holds
what that does against a physical mounting."""

from __future__ import annotations

import numpy as np
import pytest

import gtsam

from mmsnap_graph.calibration import calibrate_recording, pose_tangent_error
from mmsnap_graph.calibration.angle_bias import (
    ANGLE_BIAS_RMS_RAD,
    mounting_covariance,
    mounting_covariances,
)
from mmsnap_graph.errors import ValidationError
from mmsnap_graph.sim import CLEAN, simulate_recording

from _cli import with_centroids


@pytest.mark.parametrize("pose", [(0.0, 7.0, np.pi), (1.7, 1.65, np.pi / 2), (5.0, -2.0, 0.4)])
def test_mounting_covariance_is_the_biases_spread_in_the_pose_tangent(pose):
    """Monte Carlo of the two biases (seeded, 20,000 draws): the node's pose
    turned about the reference by b_ref and its heading by -b_n, the
    spread of its Pose2 tangent equals mounting_covariance(pose, 0) within
    4 % (sampling error about 1 % per variance; second-order terms below)."""
    rng = np.random.default_rng(3)
    s = np.deg2rad(3.0)
    b = rng.normal(0.0, s, size=(20_000, 2))
    base = gtsam.Pose2(*pose)
    tangents = []
    for b_ref, b_n in b:
        c, si = np.cos(b_ref), np.sin(b_ref)
        x, y = c * pose[0] - si * pose[1], si * pose[0] + c * pose[1]
        tangents.append(base.localCoordinates(gtsam.Pose2(x, y, pose[2] + b_ref - b_n)))
    spread = np.cov(np.array(tangents).T)
    expected = mounting_covariance(pose, np.zeros((3, 3)), angle_bias_rms_rad=s)
    # a direction the biases leave alone to first order (S2 facing S1 moves
    # across the line only) is compared at 5 % of the largest variance
    d = np.maximum(np.diag(expected), 5e-2 * np.max(np.diag(expected)))
    scale = np.sqrt(np.outer(d, d))
    np.testing.assert_allclose(spread / scale, expected / scale, atol=0.04)
    with_cov = mounting_covariance(pose, np.eye(3) * 1e-4, angle_bias_rms_rad=s)
    np.testing.assert_allclose(with_cov - expected, np.eye(3) * 1e-4, atol=1e-15)


def test_mounting_covariances_leave_the_reference_and_check_their_input():
    poses = {"S1": np.zeros(3), "S2": np.array([0.0, 7.0, np.pi])}
    covs = {"S1": np.zeros((3, 3)), "S2": np.eye(3) * 1e-4}
    out = mounting_covariances(poses, covs, "S1")
    np.testing.assert_array_equal(out["S1"], np.zeros((3, 3)))
    # S2 7 m from S1: 7 * 3 deg = 0.37 m across the line, heading sqrt(2) * 3 deg
    np.testing.assert_allclose(np.sqrt(np.diag(out["S2"])),
                               np.sqrt([1e-4 + (7 * ANGLE_BIAS_RMS_RAD) ** 2, 1e-4,
                                        1e-4 + 2 * ANGLE_BIAS_RMS_RAD**2]))
    for bad in (dict(pose=(0.0, np.nan, 0.0)), dict(covariance=np.eye(2)),
                dict(angle_bias_rms_rad=-1.0)):
        args = {"pose": (0.0, 7.0, np.pi), "covariance": np.eye(3), **bad}
        rms = args.pop("angle_bias_rms_rad", ANGLE_BIAS_RMS_RAD)
        with pytest.raises(ValidationError):
            mounting_covariance(args["pose"], args["covariance"], angle_bias_rms_rad=rms)


def _biased(rec, node_index: int, bias_rad: float):
    """``rec`` with node ``node_index``'s angles of arrival off by ``bias_rad``
    (omega = pi sin(theta) -> pi sin(theta + bias))."""
    def edit(r, w, v):
        w[:] = np.pi * np.sin(np.arcsin(np.clip(w / np.pi, -1, 1)) + bias_rad)
    return with_centroids(rec, node_index, edit)


@pytest.mark.slow
@pytest.mark.parametrize("node_index", [0, 1], ids=["reference biased", "S2 biased"])
def test_the_calibration_takes_an_angle_bias_as_heading(node_index):
    """Configuration C (S2 7 m from S1, facing it), clean model, seed 5,
    300 frames: a 4 deg angle bias of S2 turns S2's calibrated heading by
    4 deg; one of the reference turns S2 about it by -4 deg (0.49 m across
    the line). Each within 3 of the reported sigmas of the calibration
    without the bias (the data cannot tell it from the pose); the mounting
    covariance at 4 deg rms covers the error (z < 3 per component)."""
    bias = np.deg2rad(4.0)
    rec = simulate_recording("C", "random", CLEAN, levels=("centroids",), n_frames=300, seed=5)
    plain = calibrate_recording(rec)
    moved = calibrate_recording(_biased(rec, node_index, bias))
    assert plain.success and moved.success
    p, q = plain.poses["S2"], moved.poses["S2"]
    sd = np.sqrt(np.diag(plain.covariances["S2"]))
    # theta is positive toward the array axis (clockwise seen from above):
    # a biased radar sees the scene turned by -bias. S2 then turns by +bias to
    # match; the reference's frame is the reference frame: S2 turns by -bias
    # about it.
    turn = -bias if node_index == 0 else 0.0
    c, s = np.cos(turn), np.sin(turn)
    expected = np.array([c * p[0] - s * p[1], s * p[0] + c * p[1],
                         p[2] + (-bias if node_index == 0 else bias)])
    err = pose_tangent_error(q, expected)
    assert np.all(np.abs(err) <= 3 * sd), (err, sd)
    truth = rec.truth.node_poses["S2"]
    mount = mounting_covariance(q, moved.covariances["S2"], angle_bias_rms_rad=bias)
    z = pose_tangent_error(q, truth) / np.sqrt(np.diag(mount))
    assert np.all(np.abs(z) < 3.0), z
    # without the bias considered the heading (or S2's place) is many sigmas off
    z_plain = pose_tangent_error(q, truth) / np.sqrt(np.diag(moved.covariances["S2"]))
    assert np.max(np.abs(z_plain)) > 5.0, z_plain
