"""EKF track management in seconds (issue 14, Build 7): one configuration
from 5 to 30 fps; a sparse 20 fps walk is not broken into many tracks."""

import dataclasses

import numpy as np
import pytest

from factors.models import measurement_model
from mmsnap_graph.data.recording import Detections
from mmsnap_graph.errors import ConfigurationError
from mmsnap_graph.tracking.ekf import EkfConfig, track_centroids


def _sparse_walk(fps, seconds=60.0, seed=0):
    """Centroids of one walker (speed <= 1.4 m/s, 2-7 m from the radar) with
    bursts of empty frames (0.3-0.6 s every 2-4 s) and 10% random drops."""
    rng = np.random.default_rng(seed)
    t_s, n = 1.0 / fps, int(seconds * fps)
    x = np.array([0.0, 4.0, 0.8, 0.0])
    states = np.empty((n, 4))
    for i in range(n):
        a = rng.normal(0, 0.8, 2) + 0.4 * (np.array([0.0, 4.5]) - x[:2])
        x = np.array([x[0] + x[2] * t_s, x[1] + x[3] * t_s, x[2] + a[0] * t_s,
                      x[3] + a[1] * t_s])
        speed = np.hypot(x[2], x[3])
        if speed > 1.4:
            x[2:] *= 1.4 / speed
        states[i] = x
    keep = np.ones(n, bool)
    t = 0
    while t < n:
        t += int(rng.uniform(2, 4) * fps)
        keep[t:t + int(rng.uniform(0.3, 0.6) * fps)] = False
    keep &= rng.random(n) > 0.1
    f = np.flatnonzero(keep)
    z = np.array([measurement_model(s, np.zeros(3))[0] for s in states[f]])
    z += rng.normal(0, 1, z.shape) * np.array([0.05, 0.08, 0.15])
    return Detections(frame=f, range_m=z[:, 0], omega_rad=z[:, 1], doppler_mps=z[:, 2]), n


@pytest.mark.parametrize("fps", [5, 10, 20, 30])
def test_default_thresholds_keep_a_sparse_walk_in_few_tracks(fps):
    cents, n = _sparse_walk(fps)
    assert 0.15 < 1 - len(cents) / n < 0.3          # a fifth to a quarter of frames empty
    tracks = track_centroids(cents, EkfConfig(frame_period_s=1.0 / fps), frames=np.arange(n))
    assert tracks.track_ids.size <= 5
    assert np.unique(tracks.frame).size >= 0.95 * n
    if fps == 20:
        # The old counts in frames (5 misses, 3 of 5), tuned for 150 ms frames,
        # break the same walk at every gap of more than 0.25 s.
        old = track_centroids(cents, EkfConfig(frame_period_s=0.05, max_misses=5,
                                               confirm_window=5), frames=np.arange(n))
        assert old.track_ids.size >= 10


def test_frame_counts_follow_the_frame_period():
    cfg = EkfConfig()
    assert (cfg.confirm_window_frames, cfg.max_misses_frames) == (5, 5)  # 150 ms: as before
    at = {fps: dataclasses.replace(cfg, frame_period_s=1.0 / fps) for fps in (5, 20, 30)}
    assert (at[5].confirm_window_frames, at[5].max_misses_frames) == (4, 4)
    assert (at[20].confirm_window_frames, at[20].max_misses_frames) == (15, 15)
    assert (at[30].confirm_window_frames, at[30].max_misses_frames) == (23, 23)
    # At 2 fps the window still allows confirm_hits hits.
    slow = EkfConfig(frame_period_s=0.5)
    assert slow.confirm_window_frames == slow.confirm_hits == 3
    # Explicit frame counts win.
    fixed = EkfConfig(frame_period_s=0.05, max_misses=2, confirm_window=4)
    assert (fixed.confirm_window_frames, fixed.max_misses_frames) == (4, 2)


@pytest.mark.parametrize("kwargs", [{"max_coast_s": 0.0}, {"confirm_window_s": float("nan")},
                                    {"max_coast_s": True}, {"max_misses": 0},
                                    {"confirm_window": 2.5}])
def test_time_thresholds_are_checked(kwargs):
    with pytest.raises(ConfigurationError, match=next(iter(kwargs))):
        EkfConfig(**kwargs)
