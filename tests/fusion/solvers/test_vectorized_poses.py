"""Calibration-aware covariance by linear propagation
(mmsnap_graph.fusion.solvers.vectorized_poses): node poses with covariances
(Pose2 body tangent) enlarge the fused covariance, never move the estimate.

- the vectorized solver: ``P_x + A Sigma_p A^T``, checked against ``A`` from central
  differences of the solver itself;
- with the robust modes and the gate, a rejected node's pose drops out;
- Monte Carlo: with poses drawn from their reported covariance the NEES is in
  the 95% chi-square band with the option (batch and GTSAM) and out of it
  without.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from factors.models import predict_measurements
from mmsnap_graph.errors import ValidationError
from mmsnap_graph.evaluation import nees
from mmsnap_graph.fusion import FusionOptions

from _fusion import frame_of, solved
from _pose_aware import GTSAM_BATCH_TOLERANCE, NOISES, POSE_COV, pose_frames, retract
from _shared import PAPER_NOISE, POSES_BC


def fuse_batch(poses, z, **kwargs):
    """The vectorized solver through the contract."""
    return solved(poses, z, solver="vectorized", **kwargs)


def fuse_frame(poses, z, **kwargs):
    """GTSAM through the contract, one frame (its fields without the frame axis)."""
    return frame_of(solved(poses, z, solver="gtsam", **kwargs))


@pytest.mark.parametrize(
    "pose_cov, match",
    [
        (np.zeros((2, 3, 3)), r"pose_covariances must have shape \(3, 3, 3\)"),
        (np.stack([np.eye(3)] * 2 + [-np.eye(3)]),
         r"pose_covariances\[2\] must be positive definite"),
        (np.stack([np.eye(3), np.eye(3) + np.triu(np.ones((3, 3)), 1), np.eye(3)]),
         r"pose_covariances\[1\] must be symmetric"),
        (np.stack([np.eye(3), np.eye(3), np.where(np.eye(3) > 0, np.nan, 0.0)]),
         r"pose_covariances\[2\] must be finite \(or all NaN"),
    ],
)
def test_bad_pose_covariances_raise_naming_the_entry(pose_cov, match):
    _, z = pose_frames(np.random.default_rng(0), 1)
    with pytest.raises(ValidationError, match=match):
        fuse_frame(POSES_BC, z[0], pose_covariances=pose_cov)
    with pytest.raises(ValidationError, match=match):
        fuse_batch(POSES_BC, z, pose_covariances=pose_cov)


def test_exact_poses_give_the_plain_result():
    """None, all NaN and all zero all mean exact poses."""
    _, z = pose_frames(np.random.default_rng(1), 5)
    plain = fuse_batch(POSES_BC, z)
    for exact in (np.full((3, 3, 3), np.nan), np.zeros((3, 3, 3))):
        res = fuse_batch(POSES_BC, z, pose_covariances=exact)
        np.testing.assert_array_equal(res.covariance, plain.covariance)
        r = fuse_frame(POSES_BC, z[0], pose_covariances=exact)
        np.testing.assert_array_equal(r.covariance, fuse_frame(POSES_BC, z[0]).covariance)


def test_estimate_unchanged_and_covariance_grows():
    _, z = pose_frames(np.random.default_rng(2), 20)
    plain = fuse_batch(POSES_BC, z)
    aware = fuse_batch(POSES_BC, z, pose_covariances=POSE_COV)
    np.testing.assert_array_equal(aware.state, plain.state)
    np.testing.assert_array_equal(aware.success, plain.success)
    for f in range(z.shape[0]):
        assert np.linalg.eigvalsh(aware.covariance[f] - plain.covariance[f]).min() > -1e-15
        g_plain = fuse_frame(POSES_BC, z[f])
        g_aware = fuse_frame(POSES_BC, z[f], pose_covariances=POSE_COV)
        assert g_aware.success
        np.testing.assert_array_equal(g_aware.state, g_plain.state)
        assert np.linalg.eigvalsh(g_aware.covariance - g_plain.covariance).min() > -1e-15
    # 3 cm of pose error is about a node's range sigma: the position variance grows visibly.
    grow = aware.covariance[:, 0, 0] / plain.covariance[:, 0, 0]
    assert np.median(grow) > 1.1


@pytest.mark.parametrize("noisy, tolerance", [(False, 1e-4), (True, 0.05)])
def test_batch_propagation_equals_the_solvers_own_pose_sensitivity(noisy, tolerance):
    """``A = d x_hat / d xi`` by central differences of fuse_batch over each
    pose's retraction; ``P_x + A Sigma_p A^T`` is the batch answer. With
    noise-free measurements (residuals ~0: Gauss-Newton's Jacobians are the
    exact sensitivity) to 1e-4 of sigma_i sigma_j; with noisy ones the solver's
    sensitivity also holds the residual-curvature terms that the first-order
    propagation leaves out (measured: up to 2%), tolerance 5%."""
    states, z = pose_frames(np.random.default_rng(3), 8, noises=NOISES)
    if not noisy:
        z = np.stack([predict_measurements(states, p) for p in POSES_BC], axis=1)
    aware = fuse_batch(POSES_BC,
                       z,
                       noise=NOISES,
                       pose_covariances=POSE_COV,
                       options=FusionOptions(step_tolerance=1e-14))
    plain = fuse_batch(POSES_BC, z, noise=NOISES, options=FusionOptions(step_tolerance=1e-14))
    assert plain.success.all()
    h = 1e-5
    ref = plain.covariance.copy()
    for n in (1, 2):
        jac = np.zeros((z.shape[0], 4, 3))
        for k in range(3):
            xi = np.zeros(3)
            xi[k] = h
            shifted = []
            for sign in (1.0, -1.0):
                poses = POSES_BC.copy()
                poses[n] = retract(POSES_BC[n], sign * xi)
                shifted.append(fuse_batch(poses,
                                          z,
                                          noise=NOISES,
                                          initial_state=plain.state,
                                          options=FusionOptions(step_tolerance=1e-14)).state)
            jac[:, :, k] = (shifted[0] - shifted[1]) / (2 * h)
        ref += jac @ POSE_COV[n] @ np.swapaxes(jac, 1, 2)
    sig = np.sqrt(np.einsum("fii->fi", ref))
    scale = sig[:, :, None] * sig[:, None, :]
    np.testing.assert_allclose(aware.covariance / scale, ref / scale, rtol=0, atol=tolerance)


@pytest.mark.parametrize("robust", ["gate", "huber", "cauchy"])
def test_robust_modes_take_pose_covariances(robust):
    rng = np.random.default_rng(6)
    _, z = pose_frames(rng, 24, noises=NOISES)
    z[::3, 1, 0] += 2.0  # a ghost range on node 1 every third frame
    plain = fuse_batch(POSES_BC, z, noise=NOISES, robust=robust)
    aware = fuse_batch(POSES_BC, z, noise=NOISES, robust=robust, pose_covariances=POSE_COV)
    np.testing.assert_array_equal(aware.state, plain.state)
    np.testing.assert_array_equal(aware.rejected, plain.rejected)
    for f in np.flatnonzero(aware.success):
        r = fuse_frame(POSES_BC, z[f], noise=NOISES, robust=robust, pose_covariances=POSE_COV)
        np.testing.assert_allclose(r.state, aware.state[f], atol=1e-5)
        sig = np.sqrt(np.diag(aware.covariance[f]))
        assert np.max(np.abs(r.covariance - aware.covariance[f]) / np.outer(sig, sig)) \
            < GTSAM_BATCH_TOLERANCE


def test_gate_leaves_the_rejected_nodes_pose_out():
    """4 nodes, a 2 m ghost range on node 1 every third frame: the gate
    rejects node 1 there, and its pose covariance no longer counts."""
    poses = np.vstack([POSES_BC, [[5.0, 0.0, np.pi / 2]]])
    pose_cov = np.concatenate([POSE_COV, POSE_COV[1:2]])
    _, z = pose_frames(np.random.default_rng(7), 24, poses=poses, noises=(PAPER_NOISE,) * 4)
    z[::3, 1, 0] += 2.0
    aware = fuse_batch(poses, z, robust="gate", pose_covariances=pose_cov)
    gated = np.flatnonzero(aware.success & aware.rejected[:, 1])
    assert gated.size == 8
    without_1 = pose_cov.copy()
    without_1[1] = np.nan
    ref = fuse_batch(poses, z, robust="gate", pose_covariances=without_1)
    np.testing.assert_allclose(aware.covariance[gated], ref.covariance[gated], rtol=1e-12)
    for f in gated[:3]:
        r = fuse_frame(poses, z[f], robust="gate", pose_covariances=pose_cov)
        assert r.rejected[1]
        r_ref = fuse_frame(poses, z[f], robust="gate", pose_covariances=without_1)
        np.testing.assert_allclose(r.covariance, r_ref.covariance, rtol=1e-12)


@pytest.mark.slow
def test_calibration_aware_nees_in_band_when_poses_are_drawn_from_their_covariance():
    """3 nodes, S2 and S3 with 3 cm / 1 degree pose sigmas: each trial draws
    the poses used from their reported covariance (around the truth), and a
    new target and measurement noise. Mean NEES (4 dof) over the trials must
    lie in the 95% chi-square band with the pose covariances (both paths) and
    outside it without them (so the test can fail)."""
    rng = np.random.default_rng(11)
    n_trials = 1500
    used = np.broadcast_to(POSES_BC, (n_trials, 3, 3)).copy()
    chol = np.linalg.cholesky(POSE_COV[1])
    for f in range(n_trials):
        for n in (1, 2):
            used[f, n] = retract(POSES_BC[n], chol @ rng.normal(size=3))
    states, z = pose_frames(rng, n_trials)  # measured from the TRUE poses
    band = chi2.ppf([0.025, 0.975], 4 * n_trials) / n_trials

    plain = fuse_batch(used, z)
    aware = fuse_batch(used, z, pose_covariances=POSE_COV)
    ok = plain.success & aware.success
    assert ok.mean() > 0.99
    nees_plain = nees(plain.state[ok] - states[ok], plain.covariance[ok]).mean()
    nees_batch = nees(aware.state[ok] - states[ok], aware.covariance[ok]).mean()
    gtsam = [fuse_frame(used[f], z[f], pose_covariances=POSE_COV) for f in range(n_trials)]
    good = np.array([r.success for r in gtsam]) & ok
    nees_gtsam = nees(np.array([gtsam[f].state for f in np.flatnonzero(good)]) - states[good],
                      np.array([gtsam[f].covariance for f in np.flatnonzero(good)])).mean()
    assert band[0] < nees_batch < band[1], (nees_batch, band)
    assert band[0] < nees_gtsam < band[1], (nees_gtsam, band)
    assert nees_plain > band[1], (nees_plain, band)
