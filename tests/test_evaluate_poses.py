"""``mmsnap evaluate`` on a truth with surveyed node poses but no trajectory
(a real capture with a measured mounting): pose errors alone."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from mmsnap_graph.app.cli import main
from mmsnap_graph.app.evaluation import evaluate_recording
from mmsnap_graph.data.recording import Truth
from mmsnap_graph.fusion.recording.sequence import fuse_recording
from mmsnap_graph.io import write_fused, write_recording
from mmsnap_graph.sim import simulate_recording
from mmsnap_graph.sim import SimulationOptions


@pytest.fixture(scope="module")
def surveyed():
    """Configuration B with known poses; the truth keeps only the surveyed poses."""
    rec = simulate_recording("B", "random", SimulationOptions(physics=None, known_poses=True),
                             levels=("centroids",), n_frames=30, seed=2)
    truth = Truth(frame=np.zeros(0, np.int64), target_id=np.zeros(0, np.int64),
                  state=np.zeros((0, 4)), node_poses=rec.truth.node_poses)
    return dataclasses.replace(rec, truth=truth)


def test_surveyed_poses_alone_give_pose_errors_and_no_state_scores(surveyed):
    moved = {"S1": np.zeros(3), "S2": surveyed.truth.node_poses["S2"] + [0.1, -0.2, 0.03]}
    fused = fuse_recording(surveyed, progress=False)
    m = evaluate_recording(surveyed, fused=fused, node_poses=moved)
    s2 = m["poses"]["S2"]
    assert s2["position_error_m"] == pytest.approx(np.hypot(0.1, 0.2))
    assert s2["heading_error_rad"] == pytest.approx(0.03)
    assert s2["path_error_m"] is None                 # no walking path to map
    assert m["poses"]["S1"]["position_error_m"] == pytest.approx(0.0, abs=1e-12)
    # No fake state scores: nothing to compare the fused rows and tracks with.
    assert m["fused"] is None and all(v is None for v in m["tracks"].values())
    assert m["n_truth_rows"] == 0 and m["failed_checks"] == []
    assert any("no trajectory" in n for n in m["notes"])


def test_evaluate_command_on_surveyed_poses(surveyed, tmp_path, capsys):
    path = tmp_path / "surveyed.h5"
    write_recording(path, surveyed)
    write_fused(path, fuse_recording(surveyed, progress=False))
    cal = tmp_path / "cal.json"
    cal.write_text(json.dumps({"reference": "S1", "nodes": {
        "S1": {"pose": [0, 0, 0]}, "S2": {"pose": [5.0, 5.1, float(np.pi / 2)]}}}))
    assert main(["evaluate", str(path), "--calibration", str(cal), "--check"]) == 0
    text = capsys.readouterr().out
    assert "no trajectory" in text and "n/a" in text
    assert main(["evaluate", str(path), "--calibration", str(cal), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["poses"]["S2"]["position_error_m"] == pytest.approx(0.1)
    assert data["poses"]["S2"]["path_error_m"] is None and data["fused"] is None
