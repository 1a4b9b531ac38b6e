"""Calibration-aware fusion in the vectorized solver
(mmsnap_graph.fusion.solvers.vectorized_poses): the pose uncertainty added by
linear propagation equals the solver's own sensitivity to the poses."""

from __future__ import annotations

import numpy as np
import pytest

from _shared import PAPER_NOISE, POSES_BC
from factors.models import predict_measurements, wrap_angle
from mmsnap_graph import MeasurementNoise, fuse_batch
from mmsnap_graph.fusion import FusionOptions


#: 3 cm and 1 degree on the two non-reference poses; S1 is exact (all NaN).
POSE_SIGMAS = np.array([0.03, 0.03, np.deg2rad(1.0)])
POSE_COV = np.stack([np.full((3, 3), np.nan), np.diag(POSE_SIGMAS**2), np.diag(POSE_SIGMAS**2)])
NOISES = (PAPER_NOISE, MeasurementNoise(range_m=0.05, omega_rad=0.5, doppler_mps=0.15),
          MeasurementNoise(range_m=0.03, omega_rad=0.9, doppler_mps=0.2))


def _retract(pose, xi):
    """``Pose2.retract(xi)`` (GTSAM's Expmap, body tangent) in numpy."""
    x, y, phi = pose
    dx, dy, dphi = xi
    if abs(dphi) < 1e-12:
        tx, ty = dx, dy
    else:
        s, c = np.sin(dphi), np.cos(dphi)
        tx = (s * dx - (1.0 - c) * dy) / dphi
        ty = ((1.0 - c) * dx + s * dy) / dphi
    cp, sp = np.cos(phi), np.sin(phi)
    return np.array([x + cp * tx - sp * ty, y + sp * tx + cp * ty, phi + dphi])


def _frames(rng, n_frames, poses=POSES_BC, noises=(PAPER_NOISE,) * 3):
    sig = np.array([m.sigmas for m in noises])
    states = np.column_stack([rng.uniform(1.0, 4.0, n_frames), rng.uniform(1.5, 5.5, n_frames),
                              rng.normal(0.0, 0.7, (n_frames, 2))])
    if poses.ndim == 2:
        poses = np.broadcast_to(poses, (n_frames,) + poses.shape)
    z = np.stack([predict_measurements(states, poses[:, n]) for n in range(poses.shape[1])],
                 axis=1)
    z = z + rng.normal(size=z.shape) * sig
    z[..., 1] = wrap_angle(z[..., 1])
    return states, z


@pytest.mark.parametrize("noisy, tolerance", [(False, 1e-4), (True, 0.05)])
def test_batch_propagation_equals_the_solvers_own_pose_sensitivity(noisy, tolerance):
    """``A = d x_hat / d xi`` by central differences of fuse_batch over each
    pose's retraction; ``P_x + A Sigma_p A^T`` is the batch answer. With
    noise-free measurements (residuals ~0: Gauss-Newton's Jacobians are the
    exact sensitivity) to 1e-4 of sigma_i sigma_j; with noisy ones the solver's
    sensitivity also holds the residual-curvature terms that the first-order
    propagation leaves out (measured: up to 2%), tolerance 5%."""
    states, z = _frames(np.random.default_rng(3), 8, noises=NOISES)
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
                poses[n] = _retract(POSES_BC[n], sign * xi)
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
