"""Issue 11 item 4 on what a user calibrates with: the poses and covariances
that :func:`calibrate_recording` reports for a 3-node network.

By default (``method="auto"``) the reported poses are the joint calibration
graph's on the raw centroids (started from the pose graph), their
covariances its marginals; ``JointCalibration.joint_covariance`` holds the
cross-covariances, so the joint NEES of the two non-reference poses is
chi-square(6). Network of tests/test_pose_nees.py: S1 (0, 0, 0), S2 (5, 5,
pi/2), S3 (0, 7, pi); one random walker, 300 frames at 150 ms.

Measured (PYTHONPATH=. python on the functions below; band of the mean of N
chi-square(6)):
- centroids only, seeds 0-59: mean joint NEES 5.88 in (5.16, 6.91) (seeds
  0-39: 5.98 in (4.97, 7.12)); per
  node 2.84 / 3.14 in (2.41, 3.65).
- EKF tracks and centroids (the pose graph from the tracks, the joint graph
  on the centroids), seeds 0-39: 16.4 before the lag re-centring (4 seeds
  with S2 or S3 one frame off: the nodes' EKF delays differ; pose errors
  of 0.4 m), 5.98 with it (``joint.LAG_RECENTRE_FRACTION``), band (4.97,
  7.12); seeds 0-19: 5.78, band (4.58, 7.61).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.stats import chi2

from mmsnap_graph.calibration import JointOptions
from factors.models import detection_to_local, measurement_model
from mmsnap_graph.calibration import (LocalTracks, calibrate_recording, joint_calibration,
                                      pose_tangent_error)
from mmsnap_graph.calibration.joint import solve as joint_module
from mmsnap_graph.calibration.pairwise.centroid_points import debias_centroid_tracks
from mmsnap_graph.data.noise import MeasurementNoise
from mmsnap_graph.sim import simulate_recording
from mmsnap_graph.tracking.ekf import EkfConfig, track_centroids
from mmsnap_graph.sim import CLEAN

NET = {"S1": [0.0, 0.0, 0.0], "S2": [5.0, 5.0, np.pi / 2], "S3": [0.0, 7.0, np.pi]}
#: The simulator's centroid noise (sim.simulator.CENTROID_NOISE).
NOISE = MeasurementNoise(range_m=0.05, omega_rad=0.08, doppler_mps=0.10)


def _recording(seed, with_tracks=False):
    rec = simulate_recording(NET, "random", CLEAN, levels=("centroids",), n_frames=300, seed=seed)
    if with_tracks:
        cfg = EkfConfig(frame_period_s=rec.frame_period_s)
        rec = dataclasses.replace(rec, nodes={
            n: dataclasses.replace(node, tracks=track_centroids(node.centroids, cfg))
            for n, node in rec.nodes.items()})
    return rec


def _reported_joint_nees(seed, with_tracks=False):
    """Joint NEES (6 dof) of what calibrate_recording reports."""
    rec = _recording(seed, with_tracks)
    cal = calibrate_recording(rec)
    assert cal.success and cal.method == "joint", cal.message
    order = cal.joint.joint_order
    assert order == ("S2", "S3")
    e = np.concatenate([pose_tangent_error(cal.poses[n], rec.truth.node_poses[n]) for n in order])
    return float(e @ np.linalg.solve(cal.joint.joint_covariance, e))


def test_joint_covariance_holds_the_marginals():
    """The joint covariance's diagonal blocks are the reported marginals;
    it is symmetric positive definite with nonzero cross-covariances."""
    cal = calibrate_recording(_recording(0))
    jc = cal.joint.joint_covariance
    assert jc.shape == (6, 6)
    np.testing.assert_allclose(jc, jc.T, atol=0)
    assert np.all(np.linalg.eigvalsh(jc) > 0)
    np.testing.assert_allclose(jc[:3, :3], cal.covariances["S2"], rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(jc[3:, 3:], cal.covariances["S3"], rtol=1e-9, atol=1e-15)
    cross = jc[:3, 3:] / np.sqrt(np.outer(np.diag(jc)[:3], np.diag(jc)[3:]))
    assert np.max(np.abs(cross)) > 0.05, cross


@pytest.mark.parametrize("recentre", [True, False])
def test_a_lag_one_frame_off_is_recentred(monkeypatch, recentre):
    """The joint graph given S2's whole-frame lag one frame off (1 instead of
    0, what EKF tracks' matching gave on seeds 16, 22, 29): with the
    re-centring the lag of the final solve is 0, the clock offset within 20
    ms of 0 and S2 within 0.1 m; without it (threshold out of reach) the
    offset recovers only part of the frame and S2 is off by more than 0.2 m
    (measured 0.43 m)."""
    if not recentre:
        monkeypatch.setattr(joint_module, "LAG_RECENTRE_FRACTION", 10.0)
    rec = _recording(16)
    lags = {"S1": 0, "S2": 1, "S3": 0}
    dets = {n: dataclasses.replace(node.centroids, frame=node.centroids.frame - lags[n])
            for n, node in rec.nodes.items()}
    res = joint_calibration(dets, JointOptions(motion=True, sigma_a_mps2=3.0, time_offsets=True),
                            noise=NOISE, frame_period_s=rec.frame_period_s, lag_frames=lags,
                            initial_poses=NET)
    err = np.hypot(*pose_tangent_error(res.poses["S2"], NET["S2"])[:2])
    if recentre:
        assert res.lag_frames["S2"] == 0
        assert abs(res.time_offset_s["S2"]) < 0.02, res.time_offset_s
        assert err < 0.1, err
    else:
        assert res.lag_frames["S2"] == 1
        assert err > 0.2, err


def test_debiased_centroids_lose_the_boresight_bias():
    """40000 centroids of one target at 5 m, 30 degrees off boresight, omega
    sigma 0.08: detection_to_local's boresight coordinate falls short by
    R sigma_s^2 / (2 c^3) = 2.5 mm (errors against the measured range times
    the true cosine, so that the range noise cancels: standard error of the
    mean 0.37 mm); debiased, the mean error is within 3 standard errors of
    zero, the lateral coordinate is unchanged and the estimated sigma within
    3 % of 0.08. Tracks with covariances (an EKF's) are returned unchanged."""
    rng = np.random.default_rng(3)
    n = 40000
    theta = np.radians(30)
    state = np.tile([5.0 * np.sin(theta), 5.0 * np.cos(theta), 0.0, 0.0], (n, 1))
    h, _ = measurement_model(state, np.zeros(3))
    z = h + rng.normal(size=(n, 3)) * NOISE.sigmas
    pts = detection_to_local(z[:, 0], z[:, 1])
    tracks = LocalTracks(frame=np.arange(n), points_m=pts, track_id=np.zeros(n, int),
                         source="centroids")
    err = pts[:, 1] - z[:, 0] * np.cos(theta)
    se = err.std() / np.sqrt(n)
    assert err.mean() < -4 * se, (err.mean(), se)
    fixed, sigma = debias_centroid_tracks(tracks)
    err = fixed.points_m[:, 1] - z[:, 0] * np.cos(theta)
    assert abs(err.mean()) < 3 * se, (err.mean(), se)
    np.testing.assert_array_equal(fixed.points_m[:, 0], pts[:, 0])
    assert abs(sigma / 0.08 - 1) < 0.03, sigma
    ekf = dataclasses.replace(tracks, source="tracks", covariances=np.tile(np.eye(2), (n, 1, 1)))
    same, sigma = debias_centroid_tracks(ekf)
    assert same is ekf and np.isnan(sigma)


@pytest.mark.slow
def test_centroid_network_nees_in_band():
    """Centroids only, seeds 0-39: the mean joint NEES of the reported poses
    is in the band of 40 chi-square(6) (module doc for the figure)."""
    seeds = range(40)
    band = chi2.ppf([0.025, 0.975], 6 * len(seeds)) / len(seeds)
    mean = np.mean([_reported_joint_nees(s) for s in seeds])
    assert band[0] < mean < band[1], (mean, band)


@pytest.mark.slow
def test_tracks_and_centroids_network_nees_in_band():
    """EKF tracks and centroids, seeds 0-19 (module doc: 5.78)."""
    seeds = range(20)
    band = chi2.ppf([0.025, 0.975], 6 * len(seeds)) / len(seeds)
    mean = np.mean([_reported_joint_nees(s, with_tracks=True) for s in seeds])
    assert band[0] < mean < band[1], (mean, band)


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="EKF tracks only (no centroids: the pose graph is "
                   "reported), seeds 0-11: mean joint NEES 32.2 against the band (4.20, 8.11); "
                   "the tracks' EKF bias (module doc of tests/test_pose_nees.py) and lags one "
                   "frame off (seeds 2, 8: NEES 76, 85) are not fixed")
def test_tracks_only_network_nees_in_band():
    seeds = range(12)
    band = chi2.ppf([0.025, 0.975], 6 * len(seeds)) / len(seeds)
    nees = []
    for s in seeds:
        rec = _recording(s, with_tracks=True)
        rec = dataclasses.replace(rec, nodes={n: dataclasses.replace(node, centroids=None)
                                              for n, node in rec.nodes.items()})
        cal = calibrate_recording(rec)
        assert cal.method == "pose_graph"
        pg = cal.pose_graph
        e = np.concatenate([pose_tangent_error(cal.poses[n], rec.truth.node_poses[n])
                            for n in pg.joint_order])
        nees.append(float(e @ np.linalg.solve(pg.joint_covariance, e)))
    assert band[0] < np.mean(nees) < band[1], (np.mean(nees), band)
