"""Issue 14 item 7: the calibration covariance accounts for frame-to-frame
correlated residuals. EKF tracks of a simulated walk (configuration C, 400
frames at 150 ms, seeds 0-11) are split in two halves of 200 frames; each
half is calibrated by :func:`match_tracks`. The squared Mahalanobis distance
between the halves' poses, ``d^T (P_1 + P_2)^{-1} d``, is chi-square(3) when
the reported covariances are honest: its mean over 12 seeds must lie in the
95% band of the mean of 12 chi-square(3) draws, (1.79, 4.50).

Measured: 2.44 with the effective-sample-size correction (autocorrelation
factor 4-6 per half); 8.30 without (``autocorrelation="none"``), far above
the band: the test fails without the correction."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.stats import chi2

from mmsnap_graph.calibration import MatchingOptions
from mmsnap_graph.calibration import LocalTracks, local_tracks, match_tracks, pose_tangent_error
from mmsnap_graph.calibration.pairwise.effective_samples import autocorrelation_factor
from mmsnap_graph.sim import simulate_recording
from mmsnap_graph.tracking.ekf import EkfConfig, track_centroids
from mmsnap_graph.sim import CLEAN

SEEDS = range(12)
BAND = chi2.ppf([0.025, 0.975], 3 * len(SEEDS)) / len(SEEDS)


def _half(lt: LocalTracks, lo: int, hi: int) -> LocalTracks:
    m = (lt.frame >= lo) & (lt.frame < hi)
    return LocalTracks(frame=lt.frame[m], points_m=lt.points_m[m], track_id=lt.track_id[m])


def _halves_distance(seed: int, autocorrelation: str) -> float:
    rec = simulate_recording("C", "random", CLEAN, levels=("centroids",), n_frames=400, seed=seed)
    ekf = EkfConfig(frame_period_s=rec.frame_period_s)
    tracks = {n: local_tracks(dataclasses.replace(node, tracks=track_centroids(node.centroids,
                                                                                ekf)))
              for n, node in rec.nodes.items()}
    p = rec.frame_period_s  # a lag window of 2 frames, at least 5 common frames
    opts = MatchingOptions(max_lag_s=2 * p, min_common_s=5 * p, autocorrelation=autocorrelation)
    cals = [match_tracks(_half(tracks["S1"], lo, hi), _half(tracks["S2"], lo, hi),
                         frame_period_s=p, options=opts).calibration
            for lo, hi in ((0, 200), (200, 400))]
    d = pose_tangent_error(cals[0].pose, cals[1].pose)
    return float(d @ np.linalg.solve(cals[0].covariance + cals[1].covariance, d))


@pytest.mark.slow
def test_halves_of_a_recording_agree_within_their_sigmas():
    with_correction = np.mean([_halves_distance(s, "auto") for s in SEEDS])
    without = np.mean([_halves_distance(s, "none") for s in SEEDS])
    assert BAND[0] < with_correction < BAND[1], (with_correction, BAND)
    assert without > BAND[1], without  # the correction is what makes it pass


def test_white_residuals_are_not_inflated():
    """Independent scores: the factor stays near 1 (200 frames, 3 components;
    at most 1.3 in each of 20 seeds; mean under 1.15)."""
    taus = [autocorrelation_factor(np.random.default_rng(s).normal(size=(200, 3)),
                                   np.arange(200)) for s in range(20)]
    assert max(taus) < 1.3 and np.mean(taus) < 1.15, taus


def test_an_ar1_series_gets_its_integrated_autocorrelation_time():
    """AR(1) scores with coefficient 0.8: tau = (1 + 0.8) / (1 - 0.8) = 9;
    the median over 20 seeds of 2000 frames lies within 25% of it."""
    taus = []
    for s in range(20):
        rng = np.random.default_rng(100 + s)
        e = rng.normal(size=(2000, 3))
        x = np.zeros_like(e)
        for k in range(1, 2000):
            x[k] = 0.8 * x[k - 1] + e[k]
        taus.append(autocorrelation_factor(x, np.arange(2000)))
    assert abs(np.median(taus) / 9.0 - 1.0) < 0.25, np.median(taus)


def test_rows_of_one_frame_are_summed_and_gaps_tolerated():
    rng = np.random.default_rng(5)
    g = rng.normal(size=(100, 2))
    frames = np.concatenate([np.arange(50), np.arange(10_000, 10_050)])
    assert autocorrelation_factor(g, frames) < 1.5
    assert autocorrelation_factor(g[:5], np.arange(5)) == 1.0  # too short: no correction
    assert autocorrelation_factor(np.zeros((40, 3)), np.arange(40)) == 1.0


def test_times_at_both_ends_of_int64_are_a_long_gap():
    """Before: the dense time axis's size came from a wrapped np.diff (frames
    at both ends of int64): ValueError out of `mmsnap calibrate`."""
    rng = np.random.default_rng(2)
    s = rng.standard_normal((40, 2))
    near = np.concatenate([np.arange(20), np.arange(20) + 10 ** 6])
    big = np.iinfo(np.int64)
    far = np.concatenate([np.arange(20) + big.min, np.arange(20) + big.max - 19])
    assert autocorrelation_factor(s, far) == autocorrelation_factor(s, near)
