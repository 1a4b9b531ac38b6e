"""Calibration-aware fusion in the GTSAM solver
(mmsnap_graph.fusion.solvers.gtsam_poses): the covariance is the state's
marginal in the joint graph of the state and the uncertain poses."""

from __future__ import annotations

import numpy as np

from _shared import PAPER_NOISE, PAPER_PRIOR, POSES_BC
from factors.models import measurement_model_pose, predict_measurements, wrap_angle
from mmsnap_graph import MeasurementNoise, fuse_frame


#: 3 cm and 1 degree on the two non-reference poses; S1 is exact (all NaN).
POSE_SIGMAS = np.array([0.03, 0.03, np.deg2rad(1.0)])
POSE_COV = np.stack([np.full((3, 3), np.nan), np.diag(POSE_SIGMAS**2), np.diag(POSE_SIGMAS**2)])
NOISES = (PAPER_NOISE, MeasurementNoise(range_m=0.05, omega_rad=0.5, doppler_mps=0.15),
          MeasurementNoise(range_m=0.03, omega_rad=0.9, doppler_mps=0.2))


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
    _, z = _frames(np.random.default_rng(4), 10, noises=NOISES)
    for f in range(z.shape[0]):
        r = fuse_frame(POSES_BC, z[f], noise=NOISES, pose_covariances=POSE_COV)
        assert r.success
        ref = _joint_marginal(r.state, POSES_BC, z[f], NOISES, POSE_COV, PAPER_PRIOR)
        sig = np.sqrt(np.diag(ref))
        np.testing.assert_allclose(r.covariance / np.outer(sig, sig),
                                   ref / np.outer(sig, sig), rtol=0, atol=1e-7)
