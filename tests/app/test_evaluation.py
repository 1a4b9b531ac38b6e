"""``mmsnap evaluate`` and the recording-level metrics of mmsnap_graph.app.evaluation."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from mmsnap_graph.app.cli import main
from mmsnap_graph.errors import ValidationError
from mmsnap_graph.app.evaluation import evaluate_recording
from mmsnap_graph.evaluation import pose_mapping_error, state_errors, truth_reference
from mmsnap_graph.io import write_recording
from mmsnap_graph.data.recording import Tracks
from mmsnap_graph.fusion.recording.sequence import fuse_recording
from mmsnap_graph.io.fused import write_fused
from mmsnap_graph.sim import simulate_recording
from mmsnap_graph.sim import SimulationOptions
from _fusion import config


# ----------------------------------------------------------------------------
# Array-level helpers
# ----------------------------------------------------------------------------


def test_pose_mapping_error_of_a_pure_translation_is_the_translation():
    rng = np.random.default_rng(0)
    pts = rng.uniform(-3, 3, (20, 2))
    truth = np.array([5.0, 5.0, np.pi / 2])
    assert pose_mapping_error(truth + [0.1, -0.2, 0.0], truth, pts) == pytest.approx(np.hypot(0.1, 0.2))
    assert pose_mapping_error(truth, truth, pts) == pytest.approx(0.0, abs=1e-12)


def test_pose_mapping_error_of_a_rotation_grows_with_the_distance():
    truth = np.zeros(3)
    est = np.array([0.0, 0.0, 0.01])
    near = pose_mapping_error(est, truth, np.array([[0.0, 1.0]]))
    far = pose_mapping_error(est, truth, np.array([[0.0, 5.0]]))
    assert near == pytest.approx(2 * np.sin(0.005), rel=1e-9)
    assert far == pytest.approx(5 * near, rel=1e-9)


@pytest.mark.parametrize("args, match", [
    ((np.zeros(2), np.zeros(3), np.zeros((1, 2))), "poses must have shape"),
    ((np.zeros(3), np.zeros(3), np.zeros((0, 2))), "points_m must have shape"),
    ((np.zeros(3), np.zeros(3), np.zeros(2)), "points_m must have shape"),
])
def test_pose_mapping_error_rejects_bad_shapes(args, match):
    with pytest.raises(ValidationError, match=match):
        pose_mapping_error(*args)


def test_truth_reference_picks_the_nearest_target_of_the_frame():
    tf = np.array([0, 0, 1])
    tt = np.array([0, 1, 0])
    ts = np.array([[0, 0, 1, 0], [5, 5, 0, 1], [1, 0, 1, 0]], dtype=float)
    ref, tid = truth_reference([0, 0, 1, 2], [[4.5, 5.2], [0.1, 0.0], [0, 0], [0, 0]], tf, tt, ts)
    np.testing.assert_array_equal(tid, [1, 0, 0, -1])
    np.testing.assert_array_equal(ref[0], ts[1])
    np.testing.assert_array_equal(ref[2], ts[2])
    assert np.all(np.isnan(ref[3]))


def test_truth_reference_rejects_disagreeing_shapes():
    with pytest.raises(ValidationError, match="frames"):
        truth_reference([0, 1], np.zeros((3, 2)), [0], [0], np.zeros((1, 4)))
    with pytest.raises(ValidationError, match="truth_frame"):
        truth_reference([0], np.zeros((1, 2)), [0, 1], [0], np.zeros((2, 4)))


# ----------------------------------------------------------------------------
# Recordings
# ----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def processed(tmp_path_factory):
    """A configuration B recording with known poses, EKF tracks and /fused."""
    from mmsnap_graph.app.pipeline import track_recording

    rec = simulate_recording("B", "random", SimulationOptions(physics=None, known_poses=True),
                             levels=("centroids",), n_frames=80, seed=4)
    rec, _ = track_recording(rec)
    fused = fuse_recording(rec, config(), progress=False)
    path = tmp_path_factory.mktemp("ev") / "rec.h5"
    write_recording(path, rec)
    write_fused(path, fused)
    return rec, fused, path


def test_evaluate_recording_matches_direct_metrics(processed):
    rec, fused, _ = processed
    m = evaluate_recording(rec, fused=fused)
    _, truth = rec.truth.target(0)
    ok = fused.success
    direct = state_errors(fused.state[ok], truth[fused.frame[ok]])
    assert m["fused"]["position_rmse_m"] == pytest.approx(direct.position_rmse_m, rel=1e-12)
    assert m["fused"]["velocity_rmse_mps"] == pytest.approx(direct.velocity_rmse_mps, rel=1e-12)
    assert m["fused"]["n_frames"] == int(ok.sum())
    every = ok & fused.observed.all(axis=1)
    both = state_errors(fused.state[every], truth[fused.frame[every]])
    assert m["fused"]["observed_by_all_nodes"]["n_frames"] == int(every.sum())
    assert m["fused"]["observed_by_all_nodes"]["position_rmse_m"] == pytest.approx(
        both.position_rmse_m, rel=1e-12)
    # Known poses: zero pose errors; tracks evaluated with them.
    for name in ("S1", "S2"):
        assert m["poses"][name]["position_error_m"] == pytest.approx(0.0, abs=1e-12)
        assert m["tracks"][name]["n_rows"] == len(rec.nodes[name].tracks)
        assert 0 < m["tracks"][name]["position_rmse_m"] < 1.0
    nz = m["fused"]["nees"]
    assert nz["n"] == int(ok.sum()) and nz["interval_95"][0] < 4 < nz["interval_95"][1]
    assert nz["mean"] > 0
    assert m["notes"] == []


def test_evaluate_recording_with_a_wrong_calibration(processed):
    rec, fused, _ = processed
    wrong = {"S1": np.zeros(3), "S2": rec.truth.node_poses["S2"] + [0.3, 0.0, 0.0]}
    m = evaluate_recording(rec, fused=fused, node_poses=wrong)
    assert m["poses"]["S2"]["position_error_m"] == pytest.approx(0.3)
    assert m["poses"]["S2"]["path_error_m"] == pytest.approx(0.3)
    right = evaluate_recording(rec, fused=fused)
    assert m["tracks"]["S2"]["position_rmse_m"] > right["tracks"]["S2"]["position_rmse_m"]


def test_evaluate_recording_notes_what_is_missing(recording_c_straight):
    rec = recording_c_straight
    node = dataclasses.replace(rec.nodes["S2"], tracks=Tracks(
        frame=[0], track_id=[0], state=[[0, 3, 0, 0]], covariance=np.eye(4)[None]))
    m = evaluate_recording(rec.with_node(node))
    assert m["fused"] is None and m["poses"]["S2"] is None and m["tracks"]["S2"] is None
    assert any("no calibrated pose" in n for n in m["notes"])
    assert any("mmsnap fuse" in n for n in m["notes"])
    assert any("tracks not evaluated" in n for n in m["notes"])
    with pytest.raises(ValidationError, match="no truth"):
        evaluate_recording(dataclasses.replace(rec, truth=None))


def test_evaluate_command_table_and_json(processed, capsys, tmp_path):
    rec, fused, path = processed
    assert main(["evaluate", str(path)]) == 0
    text = capsys.readouterr().out
    assert "fused (map)" in text and "tracks S2" in text and "Node poses vs truth" in text
    assert main(["evaluate", str(path), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    direct = evaluate_recording(rec, fused=fused)
    assert data["fused"]["position_rmse_m"] == pytest.approx(direct["fused"]["position_rmse_m"])
    cal = tmp_path / "cal.json"
    cal.write_text(json.dumps({"reference": "S1", "nodes": {
        "S1": {"pose": [0, 0, 0]}, "S2": {"pose": [5.0, 5.1, float(np.pi / 2)]}}}))
    assert main(["evaluate", str(path), "--calibration", str(cal), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["poses"]["S2"]["position_error_m"] == pytest.approx(0.1)


def test_evaluate_command_errors(tmp_path, capsys, recording_c_straight):
    assert main(["evaluate", str(tmp_path / "missing.h5")]) == 1
    assert "missing.h5" in capsys.readouterr().err
    rec = recording_c_straight
    path = tmp_path / "no_truth.h5"
    write_recording(path, dataclasses.replace(rec, truth=None))
    assert main(["evaluate", str(path)]) == 1  # a data error, not a usage error
    assert "no truth" in capsys.readouterr().err


def test_surveyed_poses_alone_give_pose_errors_and_no_state_scores(surveyed_recording):
    moved = {"S1": np.zeros(3),
             "S2": surveyed_recording.truth.node_poses["S2"] + [0.1, -0.2, 0.03]}
    fused = fuse_recording(surveyed_recording, config(), progress=False)
    m = evaluate_recording(surveyed_recording, fused=fused, node_poses=moved)
    s2 = m["poses"]["S2"]
    assert s2["position_error_m"] == pytest.approx(np.hypot(0.1, 0.2))
    assert s2["heading_error_rad"] == pytest.approx(0.03)
    assert s2["path_error_m"] is None                 # no walking path to map
    assert m["poses"]["S1"]["position_error_m"] == pytest.approx(0.0, abs=1e-12)
    # No fake state scores: nothing to compare the fused rows and tracks with.
    assert m["fused"] is None and all(v is None for v in m["tracks"].values())
    assert m["n_truth_rows"] == 0 and m["failed_checks"] == []
    assert any("no trajectory" in n for n in m["notes"])
