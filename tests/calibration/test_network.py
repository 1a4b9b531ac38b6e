"""``calibrate_recording`` (mmsnap_graph.calibration.network): its input
checks and the poses and covariances it reports for a 3-node network.

By default (``method="auto"``) the reported poses are the joint calibration
graph's on the raw centroids (started from the pose graph), their
covariances its marginals; ``JointCalibration.joint_covariance`` holds the
cross-covariances, so the joint NEES of the two non-reference poses is
chi-square(6). Network ``_shared.NETWORK_3``: S1 (0, 0, 0), S2 (5, 5, pi/2),
S3 (0, 7, pi); one random walker, 300 frames at 150 ms
(``three_node_recording``).

Measured (band of the mean of N chi-square(6)):
- centroids only, seeds 0-59: mean joint NEES 5.88 in (5.16, 6.91) (seeds
  0-39: 5.98 in (4.97, 7.12)); per node 2.84 / 3.14 in (2.41, 3.65).
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

from mmsnap_graph.calibration import calibrate_recording, pose_tangent_error
from mmsnap_graph.errors import CalibrationError
from mmsnap_graph.sim import simulate_recording


def test_two_nodes_with_identical_centroids_are_named():
    """One log imported as two nodes: before, a singular pose graph ("Indeterminate
    linear system") or a LinAlgError from the noise estimate."""
    rec = simulate_recording("A", "straight", levels=("centroids",), n_frames=60, seed=4)
    twin = dataclasses.replace(rec.nodes["S1"], name="S2", pose=None)
    with pytest.raises(CalibrationError, match=r"nodes S1 and S2 hold the same \d+ centroids "
                                               r"in the same frames: one log imported twice"):
        calibrate_recording(rec.with_node(twin))


def _reported_joint_nees(rec):
    """Joint NEES (6 dof) of what calibrate_recording reports for ``rec``."""
    cal = calibrate_recording(rec)
    assert cal.success and cal.method == "joint", cal.message
    order = cal.joint.joint_order
    assert order == ("S2", "S3")
    e = np.concatenate([pose_tangent_error(cal.poses[n], rec.truth.node_poses[n]) for n in order])
    return float(e @ np.linalg.solve(cal.joint.joint_covariance, e))


def test_joint_covariance_holds_the_marginals(three_node_recording):
    """The joint covariance's diagonal blocks are the reported marginals;
    it is symmetric positive definite with nonzero cross-covariances."""
    cal = calibrate_recording(three_node_recording(0))
    jc = cal.joint.joint_covariance
    assert jc.shape == (6, 6)
    np.testing.assert_allclose(jc, jc.T, atol=0)
    assert np.all(np.linalg.eigvalsh(jc) > 0)
    np.testing.assert_allclose(jc[:3, :3], cal.covariances["S2"], rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(jc[3:, 3:], cal.covariances["S3"], rtol=1e-9, atol=1e-15)
    cross = jc[:3, 3:] / np.sqrt(np.outer(np.diag(jc)[:3], np.diag(jc)[3:]))
    assert np.max(np.abs(cross)) > 0.05, cross


@pytest.mark.slow
def test_centroid_network_nees_in_band(three_node_recording):
    """Centroids only, seeds 0-39: the mean joint NEES of the reported poses
    is in the band of 40 chi-square(6) (module doc for the figure)."""
    seeds = range(40)
    band = chi2.ppf([0.025, 0.975], 6 * len(seeds)) / len(seeds)
    mean = np.mean([_reported_joint_nees(three_node_recording(s)) for s in seeds])
    assert band[0] < mean < band[1], (mean, band)


@pytest.mark.slow
def test_tracks_and_centroids_network_nees_in_band(three_node_recording):
    """EKF tracks and centroids, seeds 0-19 (module doc: 5.78)."""
    seeds = range(20)
    band = chi2.ppf([0.025, 0.975], 6 * len(seeds)) / len(seeds)
    mean = np.mean([_reported_joint_nees(three_node_recording(s, with_tracks=True)) for s in seeds])
    assert band[0] < mean < band[1], (mean, band)


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="EKF tracks only (no centroids: the pose graph is "
                   "reported), seeds 0-11: mean joint NEES 32.2 against the band (4.20, 8.11); "
                   "the tracks' EKF bias (module doc of tests/test_pose_nees.py) and lags one "
                   "frame off (seeds 2, 8: NEES 76, 85) are not fixed")
def test_tracks_only_network_nees_in_band(three_node_recording):
    seeds = range(12)
    band = chi2.ppf([0.025, 0.975], 6 * len(seeds)) / len(seeds)
    nees = []
    for s in seeds:
        rec = three_node_recording(s, with_tracks=True)
        rec = dataclasses.replace(rec, nodes={n: dataclasses.replace(node, centroids=None)
                                              for n, node in rec.nodes.items()})
        cal = calibrate_recording(rec)
        assert cal.method == "pose_graph"
        pg = cal.pose_graph
        e = np.concatenate([pose_tangent_error(cal.poses[n], rec.truth.node_poses[n])
                            for n in pg.joint_order])
        nees.append(float(e @ np.linalg.solve(pg.joint_covariance, e)))
    assert band[0] < np.mean(nees) < band[1], (np.mean(nees), band)


def test_reported_lags_are_the_joint_graphs(three_node_recording):
    """``RecordingCalibration.lag_frames`` holds the lags of the solve it
    reports: the joint graph re-centres a whole-frame lag its clock offset
    only partly recovers (``calibration.joint.solve.LAG_RECENTRE_FRACTION``);
    on seed 2 the tracks' matching puts S3 at -1, the joint graph at 0 (the
    true lag)."""
    cal = calibrate_recording(three_node_recording(2, with_tracks=True))
    assert cal.method == "joint" and cal.success, cal.message
    assert cal.pose_graph.lag_frames["S3"] == -1  # the tracks' matching is one frame off
    assert dict(cal.joint.lag_frames)["S3"] == 0
    assert cal.lag_frames == {"S1": 0, "S2": 0, "S3": 0}
    assert abs(cal.time_offset_s["S3"]) < 0.02
