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
import functools
import re

import numpy as np
import pytest
from scipy.stats import chi2

from factors.models import global_to_local
from mmsnap_graph.app.pipeline import process_recording, track_recording
from mmsnap_graph.calibration import MatchingOptions, calibrate_recording, pose_tangent_error
from mmsnap_graph.calibration.network import POINT_JOINT_OPTIONS
from mmsnap_graph.data.calibration_facts import (
    ClockOffsetsTried,
    JointSkipped,
    LagEvidence,
    LagNotDetermined,
    LagsDisputed,
    PoseCovariance,
    TargetsAssociated,
)
from mmsnap_graph.data.recording import NodeData, Recording, Tracks
from mmsnap_graph.errors import CalibrationError, ValidationError
from mmsnap_graph.sim import SimulationOptions, simulate_recording
from mmsnap_graph.sim.real.sparse import sparse_clouds

from _shared import NETWORK_3_OPEN


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
    assert cal.success and cal.method == "joint", cal.facts
    order = cal.joint_order
    assert order == ("S2", "S3")
    e = np.concatenate([pose_tangent_error(cal.poses[n], rec.truth.node_poses[n]) for n in order])
    return float(e @ np.linalg.solve(cal.joint_covariance, e))


def test_joint_covariance_holds_the_marginals(three_node_recording):
    """The joint covariance's diagonal blocks are the reported marginals;
    it is symmetric positive definite with nonzero cross-covariances."""
    cal = calibrate_recording(three_node_recording(0))
    jc = cal.joint_covariance
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
def test_tracks_only_network_nees_in_band(three_node_recording):
    """EKF tracks only (no centroids: the pose graph is reported), seeds
    0-11: mean joint NEES 6.86 in the band (4.20, 8.11), per seed 2.5-11.8.
    It was 32.2 (seeds 2 and 8: 76 and 85, lags one frame off) while the EKF
    lost the walker at most turns: dozens of short tracks, each with its
    settling bias (module doc of tests/calibration/pairwise/test_pose_graph.py)."""
    seeds = range(12)
    band = chi2.ppf([0.025, 0.975], 6 * len(seeds)) / len(seeds)
    nees = []
    for s in seeds:
        rec = three_node_recording(s, with_tracks=True)
        rec = dataclasses.replace(rec, nodes={n: dataclasses.replace(node, centroids=None)
                                              for n, node in rec.nodes.items()})
        cal = calibrate_recording(rec)
        assert cal.method == "pose_graph"
        e = np.concatenate([pose_tangent_error(cal.poses[n], rec.truth.node_poses[n])
                            for n in cal.joint_order])
        nees.append(float(e @ np.linalg.solve(cal.joint_covariance, e)))
    assert band[0] < np.mean(nees) < band[1], (np.mean(nees), band)


def test_reported_lags_are_the_joint_graphs(three_node_recording):
    """``RecordingCalibration.lag_frames`` holds the lags of the solve it
    reports: the joint graph re-centres a whole-frame lag its clock offset
    only partly recovers (``calibration.joint.solve.LAG_RECENTRE_FRACTION``);
    on seed 2 the tracks' matching puts S3 at -1, the joint graph at 0 (the
    true lag)."""
    cal = calibrate_recording(three_node_recording(2, with_tracks=True))
    assert cal.method == "joint" and cal.success, cal.facts
    # The tracks' matching once found -1 here (EKF delays); the lag-evidence
    # test keeps 0 now, so the joint graph has nothing to re-centre.
    assert _matched_lag(cal, "S3") in (-1, 0)
    assert cal.lag_frames == {"S1": 0, "S2": 0, "S3": 0}
    assert abs(cal.time_offset_s["S3"]) < 0.02


def _matched_lag(cal, node):
    """The track matching's lag of ``node`` against the reference (its edge's)."""
    (lag,) = [e.lag_frames for e in cal.edges if (e.node_a, e.node_b) == (cal.reference, node)]
    return lag


def _default_path_error(rec):
    """Mean position error of S2 and S3 on the default path (``mmsnap
    process`` then ``mmsnap calibrate``), without the simulator's noise
    metadata (a real recording has none)."""
    meta = {k: v for k, v in rec.metadata.items() if not k.startswith("centroid_")}
    proc = dataclasses.replace(process_recording(rec)[0], metadata=meta)
    cal = calibrate_recording(proc)
    assert cal.success and cal.method == "joint"
    return float(np.mean([np.hypot(*pose_tangent_error(cal.poses[n], rec.truth.node_poses[n])[:2])
                          for n in ("S2", "S3")]))


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason=(
    "the target 1.2x the dense error is not reachable on these data by any estimator: the "
    "Cramer-Rao bound of the S2/S3 positions from the chain's centroids "
    "(evaluation.pose_bound, tests/evaluation/test_pose_bound.py) is, on seed 0, sparse 47 mm against "
    "dense 17 mm (2.8x; 26 against 10 mm, 2.5x, with the trajectory known), 2.5-4.7x on "
    "seeds 0-7: sparse centroids are single body points, 0.14-0.17 m range / 0.09-0.14 rad "
    "omega / 0.4-0.7 m/s Doppler about the nodes' consensus against 0.03-0.08 m / "
    "0.03-0.12 rad / 0.06-0.15 m/s dense. Measured seed 0: dense 7.0 mm, sparse 42 mm (6.0x; "
    "S3 72 mm, 1.7 of its reported 42 mm sigma); seed 1 0.72x (sparse 5.7 mm, 0.2 of its "
    "bound: luck), seed 2 2.8x"))
def test_sparse_clouds_within_1_2x_of_the_dense_case_seed_0():
    dense = simulate_recording(NETWORK_3_OPEN, "random",
                               SimulationOptions(physics=None, n_targets=2, frame_period_s=0.05),
                               levels=("point_cloud",), n_frames=600, seed=0)
    assert _default_path_error(sparse_clouds(dense, seed=0)) <= 1.2 * _default_path_error(dense)


def _duration_s(rec) -> float:
    frames = np.concatenate([n.centroids.frame for n in rec.nodes.values()])
    return float(np.ptp(frames) + 1) * rec.frame_period_s


def test_defaults_given_explicitly_give_the_same_calibration(recording_c_random):
    plain = calibrate_recording(recording_c_random, method="pose_graph")
    explicit = calibrate_recording(recording_c_random, method="pose_graph",
                                   matching=MatchingOptions(
                                       max_lag_s=0.3, min_common_s=0.5, min_spread_m=0.2,
                                       max_rmse_m=1.0, inlier_gate_m=0.5, gate_probability=0.997))
    assert plain.success and explicit.success
    np.testing.assert_array_equal(plain.poses["S2"], explicit.poses["S2"])
    assert plain.edges[0].n_frames == explicit.edges[0].n_frames


def test_min_common_s_longer_than_the_recording_fails_clearly(recording_c_random):
    rec = recording_c_random
    too_long = _duration_s(rec) + 1.0
    with pytest.raises(CalibrationError) as err:
        calibrate_recording(rec, method="pose_graph",
                            matching=MatchingOptions(min_common_s=too_long))
    text = str(err.value)
    assert f"min_common_s={too_long:g} s" in text
    need = int(np.ceil(too_long / rec.frame_period_s - 1e-9))
    assert f"shares >= {need} frames" in text
    # A tiny overlap is accepted (the 5-frame floor still applies).
    assert calibrate_recording(rec, method="pose_graph",
                               matching=MatchingOptions(min_common_s=0.0)).success


def test_min_spread_m_and_inlier_gate_m_reach_the_matching(recording_c_random):
    with pytest.raises(CalibrationError, match=r"spread >= 50\.0 m"):
        calibrate_recording(recording_c_random, method="pose_graph",
                            matching=MatchingOptions(min_spread_m=50.0))
    with pytest.raises(CalibrationError, match=r"within inlier_gate_m=0\.0001 m"):
        calibrate_recording(recording_c_random, method="pose_graph", source="centroids",
                            matching=MatchingOptions(inlier_gate_m=1e-4))
    wide = calibrate_recording(recording_c_random, method="pose_graph", source="centroids",
                               matching=MatchingOptions(inlier_gate_m=0.5))
    tight = calibrate_recording(recording_c_random, method="pose_graph", source="centroids",
                                matching=MatchingOptions(inlier_gate_m=0.2))
    assert wide.success and tight.success
    assert tight.edges[0].n_frames < wide.edges[0].n_frames


def test_gate_probability_gates_ekf_tracks(recording_c_random):
    tracked, _ = track_recording(recording_c_random)
    assert tracked.nodes["S2"].tracks.covariance is not None
    wide = calibrate_recording(tracked, method="pose_graph", source="tracks")
    tight = calibrate_recording(tracked, method="pose_graph", source="tracks",
                                matching=MatchingOptions(gate_probability=0.5))
    assert wide.success and tight.success and wide.source == "tracks"
    assert tight.edges[0].n_frames < wide.edges[0].n_frames


@pytest.mark.parametrize("kwargs, field", [
    ({"min_common_s": -1.0}, "min_common_s"),
    ({"min_common_s": float("nan")}, "min_common_s"),
    ({"min_spread_m": -0.1}, "min_spread_m"),
    ({"inlier_gate_m": 0.0}, "inlier_gate_m"),
    ({"gate_probability": 1.0}, "gate_probability"),
    ({"max_rmse_m": 0.0}, "max_rmse_m"),
    ({"max_lag_s": -0.1}, "max_lag_s"),
    ({"min_spread_m": True}, "min_spread_m"),
    ({"min_common_s": "long"}, "min_common_s"),
])
def test_bad_thresholds_name_the_field_and_value(recording_c_random, kwargs, field):
    with pytest.raises(ValidationError,
                       match=rf"^{field} must be .*got {re.escape(repr(kwargs[field]))}"):
        calibrate_recording(recording_c_random, matching=MatchingOptions(**kwargs))


def test_lag_is_found_and_used(recording_c_random):
    cal = calibrate_recording(_shift(recording_c_random, "S2", 1))
    assert cal.lag_frames == {"S1": 0, "S2": 1}
    assert cal.method == "joint"
    err = pose_tangent_error(cal.poses["S2"], recording_c_random.truth.node_poses["S2"])
    assert np.hypot(err[0], err[1]) < 0.1


def test_tracks_are_preferred_and_joint_needs_centroids(recording_c_random):
    """Tracks (here: the truth in each local frame plus 5 cm noise) are used
    when present; without centroids the joint step is skipped, or raises when
    required."""
    rng = np.random.default_rng(0)
    fr, st = recording_c_random.truth.target(0)
    nodes = {}
    for n in ("S1", "S2"):
        local = global_to_local(st[:, :2], recording_c_random.truth.node_poses[n]) + rng.normal(
            size=(fr.size, 2)) * 0.05
        state = np.column_stack([local, np.zeros((fr.size, 2))])
        nodes[n] = NodeData(name=n, tracks=Tracks(frame=fr, track_id=np.full(fr.size, 4),
                                                  state=state,
                                                  covariance=np.tile(np.eye(4), (fr.size, 1, 1))))
    rec = Recording(frame_period_s=recording_c_random.frame_period_s, nodes=nodes)
    cal = calibrate_recording(rec)
    assert cal.source == "tracks" and cal.method == "pose_graph"
    assert cal.fact(JointSkipped) is not None
    err = pose_tangent_error(cal.poses["S2"], recording_c_random.truth.node_poses["S2"])
    assert np.hypot(err[0], err[1]) < 0.05
    with pytest.raises(CalibrationError, match="needs centroids of a common target"):
        calibrate_recording(rec, method="joint")


def _shift(rec, name, lag):
    node = rec.nodes[name]
    c = dataclasses.replace(node.centroids, frame=node.centroids.frame + lag)
    return rec.with_node(dataclasses.replace(node, centroids=c))


def test_noise_is_identified_from_associated_centroids_of_two_people():
    """Two walkers, unlabelled centroids (as a TI point cloud's clusters
    are): no frame holds one centroid per node, so the nodes' own sequences
    and single-centroid frames identified none of the 6 sigmas (0 of 6,
    the paper's fallback used). The centroids the joint graph associated
    across nodes identify all 6 within 8% of the simulated 0.05 m, 0.08 rad,
    0.1 m/s (measured 0.050-0.051, 0.080-0.081, 0.108-0.109 on seeds 0-1:
    the random walk's rough speed passes a little for Doppler noise)."""
    from mmsnap_graph.sim import CLEAN
    rec = simulate_recording("B", "random", dataclasses.replace(CLEAN, n_targets=2),
                             levels=("centroids",), n_frames=300, seed=1)
    nodes = {n: dataclasses.replace(nd, centroids=dataclasses.replace(nd.centroids,
                                                                      target_id=None))
             for n, nd in rec.nodes.items()}
    meta = {k: v for k, v in rec.metadata.items() if not k.startswith("centroid_")}
    rec = track_recording(dataclasses.replace(rec, nodes=nodes, metadata=meta))[0]
    cal = calibrate_recording(rec)
    for name, est in cal.noise.nodes.items():
        assert all(est.identified), (name, est.reasons)
        np.testing.assert_allclose(est.noise.sigmas, [0.05, 0.08, 0.1], rtol=0.08)
    assert cal.method == "joint" and "associated across nodes" in cal.noise.message


_T = 0.15


def _clock_scene(poses, taus, seed, n_frames):
    """The clock-offset scene of tests/fusion/recording/test_timing.py
    (back-and-forth walk, the simulator's centroid noise), as a recording."""
    from mmsnap_graph.data.noise import MeasurementNoise
    from mmsnap_graph.sim.clocks import scene_recording, timed_scene
    from mmsnap_graph.sim.scenes import COMMON_AREA_CENTERS
    center = np.array([1.5, 3.5]) if len(poses) > 2 else COMMON_AREA_CENTERS["B"]
    scene = timed_scene(poses, time_offsets_s=taus, n_frames=n_frames, center_m=center,
                        extent_m=1.0 if len(poses) > 2 else 1.5, kind="straight",
                        noise=MeasurementNoise(range_m=0.05, omega_rad=0.08, doppler_mps=0.10),
                        rng=np.random.default_rng(seed))
    return scene_recording(scene)


@pytest.mark.parametrize("taus", [{"S2": 0.4 * _T}, {"S2": -1.3 * _T},
                                  {"S2": -1.3 * _T, "S3": 0.4 * _T}],
                         ids=["2-node+0.4", "2-node-1.3", "3-node"])
def test_clock_offsets_are_recovered_through_the_lag_rule(taus):
    """The whole path (track matching and its lag rule, the joint graph's
    fractional offsets, its lag re-centring) on synchronised-to-a-frame
    clean centroids, 2400 frames: a lag the data support is kept (the
    1.3-frame lag of S2 beats lag 0 by z 7.8-12) and every offset is within
    10 ms and 3 of its reported sigmas (seed 1 here; seeds 0-2 measured: largest error
    6.1 ms, sigmas 4.2-6.8 ms; at 600 frames the sigmas are 8.6-16 ms and
    the errors up to 26 ms: the data do not allow 10 ms there)."""
    from mmsnap_graph.sim.scenes import PAPER_CONFIGURATIONS
    poses = dict(PAPER_CONFIGURATIONS["B"])
    if len(taus) > 1:
        poses["S3"] = PAPER_CONFIGURATIONS["A"]["S2"]
    cal = calibrate_recording(_clock_scene(poses, taus, 1, 2400))
    assert cal.success and cal.method == "joint", cal.facts
    if "S3" not in taus:
        assert _matched_lag(cal, "S2") == (1 if taus["S2"] < 0 else 0)
    for name, tau in taus.items():
        err, sd = cal.time_offset_s[name] - tau, np.sqrt(cal.time_offset_variances[name])
        assert abs(err) < 0.010 and abs(err) < 3 * sd, (name, err, sd)


def test_real_physics_keeps_a_supported_whole_frame_lag_and_finds_the_fraction():
    """Real physics (clutter, splits: several centroids per frame), S2 1.3
    frames early, 600 frames: the 1-frame lag beats lag 0 on the same tracks
    (z 5.4-7.6 on seeds 0-1) and is kept; the fraction beyond it is
    estimated on the associated centroids and kept (z 4.7): -202.7 ms for
    -195 ms (seed 0; seed 2 -202.4 ms; on seed 1 no fraction was supported,
    z < 3, and the whole frame was kept). With whole frames only it was
    -150 ms."""
    from mmsnap_graph.sim.clocks import offset_recording
    rec = offset_recording("B", "straight", SimulationOptions(),
                           time_offsets_s={"S2": -1.3 * _T}, n_frames=600, seed=0)
    cal = calibrate_recording(process_recording(rec)[0])
    assert _matched_lag(cal, "S2") == 1 and cal.lag_frames["S2"] == 1
    lag = cal.fact(LagEvidence)
    assert (lag.lag_frames, lag.outcome) == (1, "determined")
    tried = cal.fact(ClockOffsetsTried)
    assert tried.outcome == "estimated" and tried.nodes == ("S2",), cal.facts
    assert -0.395 < tried.fractions[0] < -0.295, tried  # said -0.3x
    assert abs(cal.time_offset_s["S2"] + 1.3 * _T) < 0.010


def _real_clock_calibration(taus, seed, n_frames):
    """The simulator's real model (clutter, splits, ghosts: several centroids
    per frame) with clock offsets on 3 nodes (B's S2, A's S2 as S3), a
    back-and-forth walk, through ``process`` and ``calibrate``."""
    from mmsnap_graph.sim.clocks import offset_recording
    from mmsnap_graph.sim.scenes import PAPER_CONFIGURATIONS
    net = {"S1": np.zeros(3), "S2": PAPER_CONFIGURATIONS["B"]["S2"],
           "S3": PAPER_CONFIGURATIONS["A"]["S2"]}
    rec = offset_recording(net, "straight", SimulationOptions(), time_offsets_s=taus,
                           n_frames=n_frames, seed=seed)
    return calibrate_recording(process_recording(rec)[0])


@pytest.mark.slow
@pytest.mark.parametrize("taus", [{"S2": 0.4 * _T, "S3": -1.3 * _T}, {}],
                         ids=["offsets", "synchronised"])
def test_real_physics_clock_offsets_of_three_nodes(taus):
    """Several centroids per frame, 3 nodes, 1200 frames (seed 3): offsets
    of 0.4 and -1.3 frames within 10 ms and 3 of their reported sigmas (the
    whole-frame lags alone were 60 and 45 ms off); synchronised clocks get
    lag 0 and offset 0 (no fraction supported by the data). Seeds 0-3 at
    1200 frames: errors S2 -4.6 / -6.5 / +3.7 / +4.3 ms, S3 +8.3 / -7.4 /
    +5.2 / +6.9 ms (sigmas 6.1-7.7 ms); with the split-ambiguous centroids
    kept in the offset solve S3 was +13.7 / -1.4 / +9.1 / +13.4 ms (pulled
    toward the whole frame: this seed failed); synchronised: 0 on every seed
    (docs/CALIBRATION.md, "Clock offsets")."""
    cal = _real_clock_calibration(taus, 3, 1200)
    assert cal.success and cal.method == "joint", cal.facts
    assert cal.fact(TargetsAssociated) is not None
    assert cal.lag_frames == {"S1": 0, "S2": 0, "S3": 1 if taus else 0}
    for name in ("S2", "S3"):
        err = cal.time_offset_s[name] - taus.get(name, 0.0)
        assert abs(err) < 0.010, (name, err)
        if taus:
            assert abs(err) < 3 * np.sqrt(cal.time_offset_variances[name]), name
        else:
            assert cal.time_offset_s[name] == 0.0


@pytest.mark.slow
def test_a_window_edge_lag_that_loses_to_its_neighbour_hands_over_to_it():
    """The scene above on seed 4: the track matching's S1-S3 lag 2, at the
    edge of the +-2-frame window, lost to lag 1 (z = -5.2 against it) and
    lag 0 was kept; the joint graph's fractions (-1.14 and +0.54 frame,
    z 22.6 and 9.7) were then refused as beyond half a frame, and S3's
    clock came out 195 ms off (S2's 60 ms). Now lag 1 is tested against 0
    (z = 14.8) and kept: errors +4.2 and +9.0 ms (sigmas 6.9, 6.6)."""
    taus = {"S2": 0.4 * _T, "S3": -1.3 * _T}
    cal = _real_clock_calibration(taus, 4, 1200)
    assert cal.success and cal.lag_frames["S3"] == 1, cal.lag_frames
    for name in ("S2", "S3"):
        err = cal.time_offset_s[name] - taus[name]
        assert abs(err) < 0.010, (name, err)
        assert abs(err) < 3 * np.sqrt(cal.time_offset_variances[name]), name


def test_a_circle_walk_reports_its_lag_as_not_determined_with_a_covering_covariance():
    # On a circle a time shift is a turn about its centre, which the pose
    # absorbs: lags -2..2 fit about as well with poses 0.25 m apart each. The
    # joint refinement picked one lag (1 here) and reported its own covariance:
    # 0.38 m / 6.3 deg off with a 0.034 m sigma and success=True.
    from mmsnap_graph.sim import CLEAN
    f, w, r = 400, 0.5, 1.5
    t = np.arange(f) * 0.15
    walk = np.column_stack([r * np.cos(w * t), 3.5 + r * np.sin(w * t),
                            -r * w * np.sin(w * t), r * w * np.cos(w * t)])
    rec = simulate_recording("C", walk, CLEAN, levels=("centroids",), n_frames=f, seed=0)
    cal = calibrate_recording(rec)
    err = pose_tangent_error(cal.poses["S2"], rec.truth.node_poses["S2"])
    assert np.hypot(*err[:2]) > 0.2  # the data do not pin the pose down
    assert (cal.fact(LagNotDetermined).node_a, cal.fact(LagNotDetermined).node_b) == ("S1", "S2")
    d2 = float(err @ np.linalg.solve(cal.covariances["S2"], err))
    assert d2 < chi2.ppf(0.997, 3), d2


def _two_walkers_at_right_angles(seed):
    """Two random walkers seen by S1 at the origin and S2 at (1.7 m, 1.65 m,
    90 deg), synchronised, 644 frames of 50 ms, the simulator's real model
    (the geometry of the two-person recording, tools/measure_heading.py
    --simulate): the point clouds processed and calibrated."""
    from mmsnap_graph.sim.networks import Area
    from mmsnap_graph.sim.real.physics import RealPhysics
    from mmsnap_graph.sim.trajectories import random_walk
    truth = np.array([1.7, 1.65, np.pi / 2])
    area = Area(x_min_m=-1.6, x_max_m=1.3, y_min_m=0.3, y_max_m=3.2)
    options = SimulationOptions(physics=RealPhysics(room=(-2.0, 1.75, -0.05, 3.6)),
                                frame_period_s=0.05, n_targets=2, max_range_m=4.0,
                                min_range_m=0.25)
    rng = np.random.default_rng(1000 + seed)
    states = np.stack([random_walk(area, n_frames=644, frame_period_s=0.05, rng=rng)
                       for _ in range(2)])
    rec = simulate_recording({"S1": np.zeros(3), "S2": truth}, states, options,
                             levels=("point_cloud",), n_frames=644, seed=seed)
    cal = calibrate_recording(process_recording(rec)[0],
                              joint=dataclasses.replace(POINT_JOINT_OPTIONS, covariance="long_run"))
    return cal, pose_tangent_error(cal.poses["S2"], truth)


@pytest.mark.slow
def test_a_lag_of_the_tracks_alone_is_disputed_by_the_joint_graph(monkeypatch):
    # Synchronised radars (the real model, a back-and-forth walk, seed 3),
    # S2's tracks stamped 3 frames late, its centroids on time: the track
    # matching finds lag 2 (z = 16), the joint graph's clock offset on the
    # associated centroids puts it 2.30 +- 0.12 frames back. Before, lag 2
    # was kept: S2 0.30 m / 3.1 deg off (0.18 m / 1.7 deg without the delay).
    from mmsnap_graph.sim.clocks import offset_recording
    from mmsnap_graph.sim.scenes import PAPER_CONFIGURATIONS
    net = {"S1": np.zeros(3), "S2": PAPER_CONFIGURATIONS["B"]["S2"]}
    rec = process_recording(offset_recording(net, "straight", SimulationOptions(),
                                             time_offsets_s={}, n_frames=600, seed=3))[0]
    s2 = rec.nodes["S2"]
    late = dataclasses.replace(s2.tracks, frame=s2.tracks.frame + 3)
    # The second pass at lag 0 is a step of the one call, not the function
    # calling itself on the whole recording (it did: 2 calls).
    from mmsnap_graph.calibration import network
    calls = []
    whole = network.calibrate_recording
    monkeypatch.setattr(network, "calibrate_recording",
                        lambda *a, **k: calls.append(1) or whole(*a, **k))
    cal = network.calibrate_recording(dataclasses.replace(
        rec, nodes={**rec.nodes, "S2": dataclasses.replace(s2, tracks=late)}))
    assert len(calls) == 1
    assert cal.lag_frames["S2"] == 0 and cal.time_offset_s["S2"] == 0.0, cal.facts
    disputed = cal.facts[0]
    assert isinstance(disputed, LagsDisputed) and (disputed.nodes, disputed.lags) == (("S2",), (2,))
    err = pose_tangent_error(cal.poses["S2"], rec.truth.node_poses["S2"])
    assert np.hypot(*err[:2]) < 0.25 and abs(np.degrees(err[2])) < 2.5, err


@pytest.mark.slow
def test_synchronised_walkers_get_no_clock_lag():
    # Seed 1: the tracks preferred every lag up to the window's edge (-6
    # frames, z = 3.2 against 0; -1 at z = 7.4 before the EKF kept the
    # walkers through their turns), a time shift that a turn absorbs: S2
    # 16.8 deg and 0.60 m off with a 0.83 deg sigma.
    cal, err = _two_walkers_at_right_angles(1)
    assert cal.lag_frames["S2"] == 0, cal.facts
    assert abs(np.degrees(err[2])) < 2.0 and np.hypot(*err[:2]) < 0.15, err


@pytest.mark.slow
def test_an_ambiguous_lag_widens_only_by_the_lags_the_joint_graph_cannot_reject():
    # Seed 0: the track matching finds lags -4..4 about as good (RMSE within
    # 15%), with poses 2.5 deg of heading apart per frame; its spread gave a
    # 19.5 deg heading sigma where the error is 1.9 deg. The joint graph's
    # clock offset (-0.71 +- 0.24 frames) rejects every shift but one frame.
    cal, err = _two_walkers_at_right_angles(0)
    sd = np.degrees(np.sqrt(cal.covariances["S2"][2, 2]))
    assert 1.0 < sd < 5.0, (sd, cal.facts)
    assert cal.fact(LagNotDetermined).kept_shifts == (1,), cal.facts
    # The heading error within 3 sigma; the position is 0.085 m off along
    # S2's boresight (the bodies' near side: docs/CALIBRATION.md, "Extended
    # targets"), which no lag explains.
    assert abs(err[2]) < 3 * np.sqrt(cal.covariances["S2"][2, 2])


def test_calibrate_recording_defaults_follow_the_declared_target_model(recording_c_random):
    """The library's default is ``mmsnap calibrate``'s: the reflection depth's
    term in the pose covariance for people, not for point targets (the
    clean recording declares points; the same data declared as people)."""
    from mmsnap_graph.data.calibration_facts import PoseCovariance
    assert recording_c_random.targets == "points"
    points = calibrate_recording(recording_c_random)
    people = calibrate_recording(dataclasses.replace(recording_c_random, targets="people"))
    assert points.fact(PoseCovariance).reflection_depth_rms_m == 0.0
    assert people.fact(PoseCovariance).reflection_depth_rms_m > 0.05
    np.testing.assert_allclose(people.poses["S2"], points.poses["S2"], atol=1e-12)
    assert np.all(np.linalg.eigvalsh(people.covariances["S2"] - points.covariances["S2"]) > 0)


def test_the_reflection_depth_is_considered_unless_the_recording_declares_point_targets():
    """The joint graph's default by the recording's declared target model:
    people (real data, the simulator's real model, files that do not say)
    get the reflection depth's term; point targets (the clean model) do not
    (with it the README's clean tour fused at NEES 3.09, band (3.77, 4.23)).
    A metadata string no longer decides it."""
    from mmsnap_graph.calibration import (PEOPLE_JOINT_OPTIONS, POINT_JOINT_OPTIONS,
                                          joint_options_for)
    from mmsnap_graph.data.recording import NodeData, Recording

    def rec(targets=None, metadata=None):
        return Recording(frame_period_s=0.05, nodes={"S1": NodeData(name="S1")},
                         metadata=metadata or {},
                         **({} if targets is None else {"targets": targets}))

    assert joint_options_for(rec("points")) == POINT_JOINT_OPTIONS
    assert POINT_JOINT_OPTIONS.range_offset_rms_m is None
    assert joint_options_for(rec("points", {"model": "real"})) == POINT_JOINT_OPTIONS
    for r in (rec("people"), rec(), rec(metadata={"model": "clean"})):
        assert joint_options_for(r) == PEOPLE_JOINT_OPTIONS
    assert PEOPLE_JOINT_OPTIONS.range_offset_rms_m > 0.05
    with pytest.raises(ValidationError, match="targets='cars' must be one of"):
        rec("cars")


#: Two radars 8 m apart facing each other (issue 31's held-back real sessions).
FACING_8M = {"S1": np.array([0.0, 0.0, 0.0]), "S2": np.array([0.0, 8.0, np.pi])}


@functools.cache
def _facing_session(seed: int):
    """One walker seen by FACING_8M (the simulator's real model, 300 frames
    at 150 ms) through the point clouds' chain and the calibration."""
    rec = simulate_recording(FACING_8M, "random", SimulationOptions(), n_frames=300, seed=seed)
    processed, _ = process_recording(rec)
    return calibrate_recording(processed)


@pytest.mark.slow
def test_facing_radars_say_how_much_of_the_baseline_sigma_is_the_reflection_depth():
    """Facing radars see the near sides of the walker: the baseline comes
    out 2 d short, and the geometry cannot tell d from it (`--range-offset
    0.10,0.05` leaves d at 0.037 +- 0.047 m). The reported y_b sigma
    (about 0.21 m, the considered depth) covers the error against the truth
    (seeds 0-3: 0.09-0.18 m); the PoseCovariance fact says that the depth is
    most of it (y_b without it 0.009-0.021 m), and the sessions' mean error,
    the depth they share, lies far beyond the sigma without it. Measured, not
    asserted: the sessions' y_b spread is 2.2 times that sigma here (each
    seed's body differs), x_b across the baseline and the heading come out
    about 1.5 and 1.2 times their sigmas (docs/validation/calibration.md,
    "Facing radars")."""
    errors, full, free = [], [], []
    for seed in range(4):
        cal = _facing_session(seed)
        assert cal.success
        fact = cal.fact(PoseCovariance)
        assert fact.without_depth_nodes == ("S2",)
        errors.append(pose_tangent_error(cal.poses["S2"], FACING_8M["S2"]))
        full.append(np.sqrt(np.diag(cal.covariances["S2"])))
        free.append(np.asarray(fact.without_depth_sigmas))
    errors, full, free = map(np.array, (errors, full, free))
    ratio = np.var(errors[:, 1], ddof=1) / np.mean(free[:, 1] ** 2)
    print("S2 errors (x_b, y_b, phi):", np.round(errors, 4).tolist(), "reported sigma",
          np.round(full, 4).tolist(), "without the depth", np.round(free, 4).tolist(),
          f"sessions' y_b variance / without-depth variance {ratio:.2f}")
    assert np.all(np.abs(errors[:, 1]) <= 2.0 * full[:, 1])             # honest against truth
    assert np.all(free[:, 1] ** 2 < 0.2 * full[:, 1] ** 2)                # the depth's share
    np.testing.assert_allclose(free[:, [0, 2]], full[:, [0, 2]], rtol=0.05)  # across: no depth
    assert np.mean(errors[:, 1]) > 3.0 * np.sqrt(np.mean(free[:, 1] ** 2))  # the shared depth
