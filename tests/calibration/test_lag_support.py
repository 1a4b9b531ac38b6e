"""Which whole-frame lags the centroids reject (calibration/lag_support.py)."""

from __future__ import annotations

import numpy as np

from mmsnap_graph.calibration.lag_support import lags_not_rejected, unrejected_lag_spread
from mmsnap_graph.data.recording import Detections

B_POSE = np.array([1.7, 1.65, np.pi / 2])   # node b in a's frame


def _detections(points_a, rng, sigma_m=0.05):
    """Both nodes' centroids of the target at ``points_a`` (a's frame), one
    per frame, with ``sigma_m`` of Cartesian noise."""
    c, s = np.cos(B_POSE[2]), np.sin(B_POSE[2])
    rel = points_a - B_POSE[:2]
    points_b = np.column_stack([c * rel[:, 0] + s * rel[:, 1], -s * rel[:, 0] + c * rel[:, 1]])
    out = []
    for p in (points_a, points_b):
        p = p + rng.normal(0.0, sigma_m, p.shape)
        rng_m, sin_t = np.hypot(p[:, 0], p[:, 1]), p[:, 0] / np.hypot(p[:, 0], p[:, 1])
        out.append(Detections(frame=np.arange(len(p)), range_m=rng_m, omega_rad=np.pi * sin_t,
                              doppler_mps=np.zeros(len(p))))
    return out


def test_a_target_that_turns_about_rejects_every_other_lag():
    # A walk that changes direction (a figure of eight) pins the time: each
    # shift of 1-2 frames is rejected, and nothing widens.
    rng = np.random.default_rng(0)
    t = np.arange(400) * 0.05
    pts = np.column_stack([-0.2 + 1.0 * np.sin(0.8 * t), 1.8 + 0.8 * np.sin(1.6 * t)])
    a, b = _detections(pts, rng)
    pose0, tests = lags_not_rejected(a, b, [-2, -1, 1, 2], 0.5)
    assert np.allclose(pose0[:2], B_POSE[:2], atol=0.02)
    assert all(t.z >= 3.0 for t in tests), [(t.lag, t.z) for t in tests]
    extra, kept, rejected = unrejected_lag_spread(a, b, [-2, -1, 1, 2], 0.5, np.eye(3) * 1e-4)
    assert kept == [] and rejected == [-2, -1, 1, 2] and not extra.any()


def test_a_circle_walk_keeps_the_lags_a_turn_absorbs():
    # On a circle a time shift is a turn about its centre: no shift is
    # rejected, and the covariance grows by the turned poses' spread.
    rng = np.random.default_rng(1)
    t = np.arange(400) * 0.05
    pts = np.column_stack([-0.2 + 1.0 * np.cos(0.5 * t), 1.8 + 1.0 * np.sin(0.5 * t)])
    a, b = _detections(pts, rng)
    extra, kept, rejected = unrejected_lag_spread(a, b, [-2, -1, 1, 2], 0.5, np.eye(3) * 1e-4)
    assert kept == [-2, -1, 1, 2] and rejected == []
    assert np.sqrt(extra[2, 2]) > np.radians(2.0)   # 1.4 deg of turn per frame


def test_too_few_common_frames_reject_nothing():
    rng = np.random.default_rng(2)
    pts = np.column_stack([np.linspace(-1, 1, 6), np.full(6, 2.0)])
    a, b = _detections(pts, rng)
    pose0, tests = lags_not_rejected(a, b, [1], 0.5)
    assert pose0 is None and np.isnan(tests[0].z) and tests[0].pose is None
