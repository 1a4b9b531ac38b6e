"""match_tracks: the inlier gate scales with the tracks' own covariances
(issue 11 item 4) and its thresholds are in seconds (issue 14 item 7)."""

from __future__ import annotations

import numpy as np
import pytest

from mmsnap_graph.calibration import MatchingOptions
from mmsnap_graph.calibration import LocalTracks, match_tracks, pose_tangent_error
from mmsnap_graph.errors import ValidationError
from factors.models import global_to_local

TRUE_B = np.array([0.0, 7.0, np.pi])


def _far_tracks(seed, n=400, sigma_cross=0.4, sigma_range=0.03):
    """A walk 5-9 m from both nodes; each node's points carry an anisotropic
    noise (cross-range sigma_cross) and its true covariance."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.15
    xy = np.column_stack([1.5 * np.sin(0.3 * t), 3.5 + 1.5 * np.cos(0.21 * t)])
    out = []
    for pose in (np.zeros(3), TRUE_B):
        loc = global_to_local(xy, pose)
        u = loc / np.linalg.norm(loc, axis=1, keepdims=True)     # line of sight
        v = np.column_stack([-u[:, 1], u[:, 0]])
        cov = (sigma_range**2 * u[:, :, None] * u[:, None, :]
               + sigma_cross**2 * v[:, :, None] * v[:, None, :])
        noisy = loc + sigma_range * rng.normal(size=(n, 1)) * u + sigma_cross * rng.normal(
            size=(n, 1)) * v
        out.append((noisy, cov))
    frames = np.arange(n)
    a = LocalTracks(frame=frames, points_m=out[0][0], track_id=np.zeros(n, int),
                    covariances=out[0][1])
    b = LocalTracks(frame=frames, points_m=out[1][0], track_id=np.zeros(n, int),
                    covariances=out[1][1])
    plain = [LocalTracks(frame=frames, points_m=x.points_m, track_id=x.track_id) for x in (a, b)]
    return (a, b), plain


#: A nominal frame period (s) for the track tables here, and options that
#: search 2 frames of lag at it.
T = 0.1
OPTIONS = MatchingOptions(max_lag_s=2 * T, autocorrelation="none", covariance="sandwich")


def test_chi_square_gate_keeps_far_noisy_frames_and_the_nees_honest():
    """Cross-range sigma 0.4 m per node: the fixed 0.5 m gate keeps about 60%
    of the frames (measured 55-65%) and cuts the residual tails; the
    chi-square gate keeps >= 97% (its probability 0.997, minus the pose
    error). Over 20 seeds the mean pose NEES with the chi-square gate is
    within the 95% band of the mean of 20 chi-square(3), (2.0, 4.2); white
    noise, so autocorrelation="none"."""
    kept_fixed, kept_chi2, nees = [], [], []
    for seed in range(20):
        (a, b), (pa, pb) = _far_tracks(seed)
        fixed = match_tracks(pa, pb, frame_period_s=T, options=OPTIONS)
        gated = match_tracks(a, b, frame_period_s=T, options=OPTIONS)
        assert fixed.success and gated.success
        kept_fixed.append(fixed.calibration.n_frames / 400)
        kept_chi2.append(gated.calibration.n_frames / 400)
        e = pose_tangent_error(gated.calibration.pose, TRUE_B)
        nees.append(e @ np.linalg.solve(gated.calibration.covariance, e))
    assert np.mean(kept_fixed) < 0.8, np.mean(kept_fixed)
    assert np.mean(kept_chi2) > 0.97, np.mean(kept_chi2)
    assert 2.0 < np.mean(nees) < 4.2, np.mean(nees)


def test_thresholds_in_seconds():
    (a, b), _ = _far_tracks(1, sigma_cross=0.05)
    m = match_tracks(a, b, frame_period_s=0.05, options=MatchingOptions(max_lag_s=0.1))
    assert m.success
    assert {c.lag_frames for c in m.candidates} == {-2, -1, 0, 1, 2}  # 0.1 s at 20 fps
    one = match_tracks(a, b, frame_period_s=0.1, options=MatchingOptions(max_lag_s=0.1))
    assert {c.lag_frames for c in one.candidates} == {-1, 0, 1}  # 0.1 s at 10 fps
    # 0.5 s at 20 fps is 10 frames: a 8-frame overlap is refused
    short = [LocalTracks(frame=x.frame[:8], points_m=x.points_m[:8], track_id=x.track_id[:8])
             for x in (a, b)]
    assert not match_tracks(*short, frame_period_s=0.05).success
    with pytest.raises(TypeError, match="frame_period_s"):
        match_tracks(a, b, options=MatchingOptions(max_lag_s=0.3))
    with pytest.raises(ValidationError, match="frame_period_s must be finite"):
        match_tracks(a, b, frame_period_s=0.0)
    with pytest.raises(ValidationError, match="gate_probability"):
        MatchingOptions(gate_probability=1.0)
