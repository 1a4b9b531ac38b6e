"""Issue 11 item 4: 3-node network pose NEES. Network S1 (0, 0, 0), S2 (5, 5,
pi/2), S3 (0, 7, pi); one random walker, 300 frames at 150 ms; the two
non-reference poses have 6 degrees of freedom, so the joint NEES (with the
poses' cross-covariance) is chi-square(6): over N seeds its mean has the 95%
band chi2.ppf([0.025, 0.975], 6 N) / N.

Measured (seeds 0-19 unless said; the Monte Carlo functions in this file):
- White noise, points spread over a 3 m square (no tracker, no small-spread
  effect), seeds 0-99: between factors 9.25, points solve 6.39 (band for
  100 seeds (5.33, 6.70)): the shared detections, counted once.
- EKF tracks, old pose graph (independent between factors, no
  autocorrelation correction): mean joint NEES 171 (10 seeds).
- EKF tracks, points solve with the correction: 20.7 (matching with the
  fixed 0.5 m gate; 32 on seeds 0-5 with the chi-square gate); reported sigmas
  match the spread of the errors (S2 x 0.067 vs 0.065 m) but the EKF tracks
  carry a bias common to all seeds (S2 x +0.05 m, phi +0.012 rad) that no
  covariance of the residuals can show.
- Centroids: old graph 7.25 (10 seeds), points solve 7.5 (30 seeds; band
  for 30 seeds (5.0, 7.2)), between factors with the corrected pairwise
  covariances 6.05 but marginal sigmas 20x the actual errors.
- Centroids, points solve, seeds 0-199 (band (5.53, 6.49)): 6.82, of which
  0.64 is a bias common to all seeds (NEES at the mean covariance: 6.71 with
  the mean error, 6.10 without): ``detection_to_local`` maps the angle's
  noise through the concave ``sqrt(1 - s^2)``, so every centroid falls
  short along boresight by ``R sigma_s^2 / (2 c^3)`` (2-6 mm here). With
  the linearised noise instead 6.16; with the bias removed
  (:mod:`mmsnap_graph.calibration.pairwise.centroid_points`, on by default in
  ``pairwise_edges``) 6.19, bias part 0.02; seeds 0-19 7.12 (was 8.10).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.stats import chi2

from mmsnap_graph.calibration import MatchingOptions
from factors.models import global_to_local
from mmsnap_graph.calibration import (LocalTracks, local_tracks, pairwise_edges,
                                      pose_graph_calibration, pose_tangent_error)
from mmsnap_graph.sim import simulate_recording
from mmsnap_graph.tracking.ekf import EkfConfig, track_centroids
from mmsnap_graph.sim import CLEAN

NET = {"S1": [0.0, 0.0, 0.0], "S2": [5.0, 5.0, np.pi / 2], "S3": [0.0, 7.0, np.pi]}


def _joint_nees(seed, source, **options):
    rec = simulate_recording(NET, "random", CLEAN, levels=("centroids",), n_frames=300, seed=seed)
    tracks = {}
    for n, node in rec.nodes.items():
        if source == "tracks":
            node = dataclasses.replace(node, tracks=track_centroids(
                node.centroids, EkfConfig(frame_period_s=rec.frame_period_s)))
        tracks[n] = local_tracks(node, source)
    edges, failures = pairwise_edges(tracks, frame_period_s=rec.frame_period_s)
    assert not failures, failures
    pg = pose_graph_calibration(list(NET), edges, **options)
    assert pg.success, pg.message
    e = np.concatenate([pose_tangent_error(pg.poses[n], rec.truth.node_poses[n])
                        for n in pg.joint_order])
    return float(e @ np.linalg.solve(pg.joint_covariance, e))


def _synthetic_joint_nees(seed, method):
    """Three nodes see one target at 300 points spread over a 3 m square;
    white noise per node, 0.03 m along the line of sight and 0.25 m across
    (a radar's). Pairwise edges, then the pose graph."""
    rng = np.random.default_rng(seed)
    xy = np.array([0.5, 4.5]) + rng.uniform(-1.5, 1.5, size=(300, 2))
    tracks = {}
    for name, pose in NET.items():
        loc = global_to_local(xy, np.asarray(pose))
        u = loc / np.linalg.norm(loc, axis=1, keepdims=True)
        v = np.column_stack([-u[:, 1], u[:, 0]])
        noisy = loc + 0.03 * rng.normal(size=(300, 1)) * u + 0.25 * rng.normal(size=(300, 1)) * v
        tracks[name] = LocalTracks(frame=np.arange(300), points_m=noisy,
                                   track_id=np.zeros(300, int))
    # 2 frames of lag and 5 common frames at a nominal 0.1 s frame period
    edges, failures = pairwise_edges(tracks, frame_period_s=0.1, options=MatchingOptions(
        max_lag_s=0.2, max_rmse_m=5.0, inlier_gate_m=5.0, autocorrelation="none"))
    assert not failures, failures
    pg = pose_graph_calibration(list(NET), edges, method=method, autocorrelation="none")
    e = np.concatenate([pose_tangent_error(pg.poses[n], NET[n]) for n in pg.joint_order])
    return float(e @ np.linalg.solve(pg.joint_covariance, e))


@pytest.mark.slow
def test_shared_detections_are_counted_once():
    """White noise, 60 seeds: the joint NEES of the points solve is in the
    95% band of the mean of 60 chi-square(6), (5.16, 6.93) (measured 6.39
    over 100 seeds); the between-factor graph of the same pairwise edges,
    which takes them as independent, is above it (measured 9.25)."""
    seeds = range(60)
    band = chi2.ppf([0.025, 0.975], 6 * len(seeds)) / len(seeds)
    points = np.mean([_synthetic_joint_nees(s, "points") for s in seeds])
    edges = np.mean([_synthetic_joint_nees(s, "edges") for s in seeds])
    assert band[0] < points < band[1], (points, band)
    assert edges > band[1], edges


@pytest.mark.slow
def test_tracks_pose_nees_no_longer_off_by_two_orders():
    """EKF tracks, seeds 0-5 (matching in seconds, chi-square gate): the
    points solve with the autocorrelation correction gives a mean joint NEES
    of 32 (per seed 19-76: the tracks' bias, module doc), without the
    correction 183 (the old pose graph: 171). Bound: 60 (10x the
    chi-square(6) mean); the uncorrected solve must exceed it."""
    seeds = range(6)
    fixed = np.mean([_joint_nees(s, "tracks") for s in seeds])
    uncorrected = np.mean([_joint_nees(s, "tracks", autocorrelation="none") for s in seeds])
    assert fixed < 60.0, fixed
    assert uncorrected > 60.0, uncorrected


@pytest.mark.slow
def test_centroid_pose_nees_in_band():
    """Centroids, seeds 0-19: mean joint NEES of the points solve 7.12 in the
    band (4.58, 7.61) with the centroids' boresight bias removed (8.10
    without: the bias, module doc); 6.19 over seeds 0-199."""
    seeds = range(20)
    band = chi2.ppf([0.025, 0.975], 6 * len(seeds)) / len(seeds)
    mean = np.mean([_joint_nees(s, "centroids") for s in seeds])
    assert band[0] < mean < band[1], (mean, band)


def test_two_nodes_points_solve_is_the_closed_form():
    """With two nodes the points solve minimises the closed form's cost: the
    same pose (1e-9) and the sandwich covariance times n / (n - 3)."""
    from mmsnap_graph.calibration import PoseEdge, closed_form_calibration

    rng = np.random.default_rng(0)
    xy = np.array([0.5, 4.5]) + rng.uniform(-1.5, 1.5, size=(300, 2))
    pose_b = np.array([5.0, 5.0, np.pi / 2])
    za = xy + 0.1 * rng.normal(size=(300, 2))
    zb = global_to_local(xy, pose_b) + 0.1 * rng.normal(size=(300, 2))
    cf = closed_form_calibration(za, zb, covariance="sandwich", autocorrelation="none",
                                 frames=np.arange(300))
    edge = PoseEdge.from_pairwise("S1", "S2", cf)
    pg = pose_graph_calibration(["S1", "S2"], [edge], autocorrelation="none")
    assert pg.method == "points" and pg.success
    np.testing.assert_allclose(pg.poses["S2"], cf.pose, atol=1e-9)
    np.testing.assert_allclose(pg.covariances["S2"], cf.covariance * 300 / 297, rtol=1e-6)
