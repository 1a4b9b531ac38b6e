"""``mmsnap evaluate --surveyed NAME=X,Y,PHI_DEG``: surveyed node poses from
the command line (issue 14, Build 7: "evaluate scores surveyed poses alone").
Before, a TI import (no /truth) could only be scored by writing a Truth
through the Python API; the CLI said "no truth" and exited 1."""

from __future__ import annotations

import json

import numpy as np
import pytest
import h5py

from mmsnap_graph.app.cli import main
from mmsnap_graph.io import read_recording, write_fused, write_recording
from mmsnap_graph.fusion.recording.sequence import fuse_recording
from _fusion import config


@pytest.fixture(scope="module")
def imported(tmp_path_factory):
    """A calibrated recording without truth (the mounting known to the test)."""
    d = tmp_path_factory.mktemp("surveyed")
    sim = d / "sim.h5"
    assert main(["simulate", "--model", "clean", "-c", "B", "-t", "random", "-n", "40", "-l", "centroids",
                 "--seed", "3", "--known-poses", "-o", str(sim), "--no-progress"]) == 0
    import h5py
    with h5py.File(sim, "r+") as f:
        del f["truth"]
    return sim


def test_surveyed_poses_score_a_recording_without_truth(imported, capsys):
    pose = read_recording(imported).nodes["S2"].pose
    surveyed = [pose[0] + 0.03, pose[1] - 0.04, np.rad2deg(pose[2]) + 1.0]
    capsys.readouterr()
    assert main(["evaluate", str(imported), "--json", "--surveyed", "S1=0,0,0",
                 "--surveyed", "S2=" + ",".join(f"{v:.12g}" for v in surveyed)]) == 0
    m = json.loads(capsys.readouterr().out)
    assert m["poses"]["S2"]["position_error_m"] == pytest.approx(0.05, abs=1e-9)
    assert m["poses"]["S2"]["heading_error_rad"] == pytest.approx(np.deg2rad(-1.0), abs=1e-9)
    assert m["fused"] is None and m["n_truth_rows"] == 0


def test_without_surveyed_poses_no_truth_is_still_an_error_that_says_how(imported, capsys):
    assert main(["evaluate", str(imported)]) == 1
    assert "--surveyed" in capsys.readouterr().err


def test_bad_surveyed_poses_are_usage_errors(imported, capsys):
    assert main(["evaluate", str(imported), "--surveyed", "S9=0,0,0"]) == 2
    assert "no such node" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:                 # argparse
        main(["evaluate", str(imported), "--surveyed", "S2=0,7"])
    assert exc.value.code == 2
    assert "NAME=X_M,Y_M,PHI_DEG" in capsys.readouterr().err


def test_surveyed_poses_replace_the_truths_on_a_simulation(tmp_path, capsys):
    sim = tmp_path / "sim.h5"
    assert main(["simulate", "--model", "clean", "-c", "B", "-t", "random", "-n", "30", "-l", "centroids",
                 "--seed", "3", "--known-poses", "-o", str(sim), "--no-progress"]) == 0
    pose = read_recording(sim).nodes["S2"].pose
    capsys.readouterr()
    assert main(["evaluate", str(sim), "--json", "--surveyed",
                 f"S2={pose[0] + 0.1:.12g},{pose[1]:.12g},{np.rad2deg(pose[2]):.12g}"]) == 0
    m = json.loads(capsys.readouterr().out)
    assert m["poses"]["S2"]["position_error_m"] == pytest.approx(0.1, abs=1e-9)
    assert m["n_truth_rows"] > 0 and m["fused"] is None     # the trajectory is kept


def test_evaluate_on_a_fused_group_of_unequal_lengths_names_the_file(recording_b_file, tmp_path,
                                                                    capsys):
    rec = read_recording(recording_b_file)
    path = tmp_path / "f.h5"
    write_fused(recording_b_file, fuse_recording(rec, config(), progress=False), output=path)
    with h5py.File(path, "r+") as f:
        data = f["fused/x_m"][()]
        del f["fused/x_m"]
        f["fused/x_m"] = data[:-3]
    assert main(["evaluate", str(path)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(path) in err[0] and "x_m" in err[0]


def test_evaluate_command_on_surveyed_poses(surveyed_recording, tmp_path, capsys):
    path = tmp_path / "surveyed.h5"
    write_recording(path, surveyed_recording)
    write_fused(path, fuse_recording(surveyed_recording, config(), progress=False))
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


def test_a_calibration_json_without_a_node_is_refused_as_fuse_refuses_it(recording_b_file,
                                                                        tmp_path, capsys):
    """Before: evaluate --calibration with a JSON lacking S2 scored S2 at the
    recording's own pose, silently, while fuse refused the same file."""
    poses = tmp_path / "s1_only.json"
    poses.write_text(json.dumps({"nodes": {"S1": {"pose": [0.0, 0.0, 0.0]}}}))
    for argv in (["evaluate", str(recording_b_file), "--calibration", str(poses)],
                 ["fuse", str(recording_b_file), "-o", str(tmp_path / "f.h5"), "--no-progress",
                  "--calibration", str(poses)]):
        assert main(argv) == 1
        err = capsys.readouterr().err
        assert "s1_only.json has no pose for node(s) ['S2'] of the recording" in err, err
