"""Issue 13: on a circular walk the lag search picked a wrong lag and
reported a pose 0.8 m / 9 degrees off with ``success=True`` and a 0.08 m
sigma. An ambiguous lag must lower the confidence (or fail): a successful
match's pose error is within its covariance (NEES below the chi-square(3)
0.999 quantile)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from mmsnap_graph.calibration import MatchingOptions
from mmsnap_graph.calibration import local_tracks, match_tracks, pose_tangent_error
from mmsnap_graph.sim.networks import COMMON_AREAS, CONFIGURATIONS
from mmsnap_graph.sim.simulator import simulate_recording
from mmsnap_graph.sim import CLEAN


def circular_walk(seed: int):
    """Configuration, true pose of S2 and the recording of a walk around a
    circle (radius 0.5-1.4 m, 0.3-1.2 m/s, 100-400 frames)."""
    rng = np.random.default_rng(seed)
    cfg = "ABC"[seed % 3]
    c = COMMON_AREAS[cfg].center_m
    r, v, f = rng.uniform(0.5, 1.4), rng.uniform(0.3, 1.2), int(rng.integers(100, 400))
    t, w, ph = np.arange(f) * 0.15, v / r, rng.uniform(0, 2 * np.pi)
    a = w * t + ph
    states = np.column_stack([c[0] + r * np.cos(a), c[1] + r * np.sin(a),
                              -r * w * np.sin(a), r * w * np.cos(a)])
    rec = simulate_recording(cfg, states, CLEAN, levels=("centroids",), n_frames=f, seed=seed)
    return CONFIGURATIONS[cfg]["S2"], rec


# seeds 0, 13, 14, 26, 31 gave lags -2, -2, -1, 1, 2 and errors of 0.2-1.2 m
@pytest.mark.parametrize("seed", [0, 13, 14, 26, 31, 1, 2])
def test_an_ambiguous_lag_does_not_give_a_confident_wrong_pose(seed):
    truth, rec = circular_walk(seed)
    p = rec.frame_period_s  # a lag window of 2 frames, at least 5 common frames
    m = match_tracks(local_tracks(rec.nodes["S1"]), local_tracks(rec.nodes["S2"]),
                     frame_period_s=p, options=MatchingOptions(max_lag_s=2 * p,
                                                               min_common_s=5 * p))
    if not m.success:
        return
    e = pose_tangent_error(m.calibration.pose, truth)
    nees = e @ np.linalg.solve(m.calibration.covariance, e)
    assert nees < chi2.ppf(0.999, 3), (m.lag_frames, e, m.calibration.covariance)


def test_lag_ambiguity_is_validated():
    truth, rec = circular_walk(1)
    with pytest.raises(Exception, match="lag_ambiguity"):
        match_tracks(local_tracks(rec.nodes["S1"]), local_tracks(rec.nodes["S2"]),
                     frame_period_s=rec.frame_period_s,
                     options=MatchingOptions(lag_ambiguity=float("nan")))
