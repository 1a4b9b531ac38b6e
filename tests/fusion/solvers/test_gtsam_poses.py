"""Calibration-aware covariance of one frame with GTSAM
(mmsnap_graph.fusion.solvers.gtsam_poses): node poses with covariances
(Pose2 body tangent) become ``Pose2`` variables under priors; the fused
covariance is ``gtsam.Marginals``' of that graph, checked against the dense
joint information computed here and against the batch propagation
(tests/fusion/solvers/test_vectorized_poses.py)."""

from __future__ import annotations

import numpy as np
import pytest

from factors.models import measurement_model_pose
from _fusion import solved
from mmsnap_graph.errors import ValidationError
from mmsnap_graph.fusion import FusionOptions

from _pose_aware import GTSAM_BATCH_TOLERANCE, NOISES, POSE_COV, pose_frames
from _shared import PAPER_PRIOR, POSES_BC


def test_grid_covariance_refuses_pose_covariances():
    _, z = pose_frames(np.random.default_rng(0), 1)
    with pytest.raises(ValidationError, match="pose_covariances need covariance='laplace'"):
        solved(POSES_BC, z[0], pose_covariances=POSE_COV,
               options=FusionOptions(covariance="grid"))


def _joint_marginal(state, poses, z, noises, pose_cov, prior):
    """The dense joint information of (state, uncertain poses) at the given
    point, state block marginalized (what gtsam.Marginals computes)."""
    uncertain = [n for n in range(len(poses)) if not np.isnan(pose_cov[n]).all()]
    dim = 4 + 3 * len(uncertain)
    info = np.zeros((dim, dim))
    info[:4, :4] = prior.information
    for n, pose in enumerate(poses):
        _, j_pose, j_state = measurement_model_pose(pose, state)
        jac = np.zeros((3, dim))
        jac[:, :4] = j_state
        if n in uncertain:
            b = 4 + 3 * uncertain.index(n)
            jac[:, b:b + 3] = j_pose
            info[b:b + 3, b:b + 3] += np.linalg.inv(pose_cov[n])
        info += jac.T @ np.diag(1.0 / noises[n].sigmas ** 2) @ jac
    return np.linalg.inv(info)[:4, :4]


def test_gtsam_covariance_is_the_joint_graph_marginal():
    _, z = pose_frames(np.random.default_rng(4), 10, noises=NOISES)
    res = solved(POSES_BC, z, noise=NOISES, pose_covariances=POSE_COV)
    assert res.success.all()
    for f in range(z.shape[0]):
        ref = _joint_marginal(res.state[f], POSES_BC, z[f], NOISES, POSE_COV, PAPER_PRIOR)
        sig = np.sqrt(np.diag(ref))
        np.testing.assert_allclose(res.covariance[f] / np.outer(sig, sig),
                                   ref / np.outer(sig, sig), rtol=0, atol=1e-7)


def test_gtsam_and_batch_agree_to_the_stated_tolerance():
    _, z = pose_frames(np.random.default_rng(5), 40, noises=NOISES)
    res = solved(POSES_BC, z, solver="vectorized", noise=NOISES, pose_covariances=POSE_COV)
    ref = solved(POSES_BC, z, noise=NOISES, pose_covariances=POSE_COV)
    np.testing.assert_array_equal(res.status, ref.status)
    gaps = []
    for f in range(z.shape[0]):
        np.testing.assert_allclose(res.state[f], ref.state[f], rtol=0, atol=1e-6)
        sig = np.sqrt(np.diag(res.covariance[f]))
        gaps.append(np.max(np.abs(res.covariance[f] - ref.covariance[f]) / np.outer(sig, sig)))
        # The propagation is never the smaller (the joint graph uses more information).
        assert np.linalg.eigvalsh(res.covariance[f] - ref.covariance[f]).min() > -1e-12
    assert max(gaps) < GTSAM_BATCH_TOLERANCE, max(gaps)
