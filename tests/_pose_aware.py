"""Frames and node pose covariances shared by the calibration-aware fusion
tests (tests/fusion/solvers/test_vectorized_poses.py, test_gtsam_poses.py,
tests/fusion/recording/test_sequence.py, tests/fusion/stream/test_frame_stream.py).

Network ``_shared.POSES_BC`` (S1 and the S2 of configurations B and C);
S1 exact, S2 and S3 with 3 cm / 1 degree pose sigmas (Pose2 body tangent).
"""

from __future__ import annotations

import numpy as np

from factors.models import predict_measurements, wrap_angle
from mmsnap_graph import MeasurementNoise

from _shared import PAPER_NOISE, POSES_BC

#: 3 cm and 1 degree on the two non-reference poses; S1 is exact (all NaN).
POSE_SIGMAS = np.array([0.03, 0.03, np.deg2rad(1.0)])
POSE_COV = np.stack([np.full((3, 3), np.nan), np.diag(POSE_SIGMAS**2), np.diag(POSE_SIGMAS**2)])
NOISES = (PAPER_NOISE, MeasurementNoise(range_m=0.05, omega_rad=0.5, doppler_mps=0.15),
          MeasurementNoise(range_m=0.03, omega_rad=0.9, doppler_mps=0.2))

#: GTSAM's joint-graph marginal against the batch propagation: the joint graph
#: also uses what this frame's measurements say about the poses, so it is the
#: smaller by up to ~7% of sigma_i sigma_j here (measured: median 3.9%, max
#: 6.9% over 200 frames of this network); tolerance 10%.
GTSAM_BATCH_TOLERANCE = 0.10


def retract(pose, xi):
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


def pose_frames(rng, n_frames, poses=POSES_BC, noises=(PAPER_NOISE,) * 3):
    """``n_frames`` random target states (1-4 m by 1.5-5.5 m, 0.7 m/s) and
    their noisy measurements ``(F, N, 3)`` from ``poses``."""
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
