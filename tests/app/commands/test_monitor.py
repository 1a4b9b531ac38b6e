"""``mmsnap monitor`` (app.commands.monitor), registered in a throwaway parser
(the lead adds "monitor" to app.cli.COMMANDS)."""

from __future__ import annotations

from mmsnap_graph.errors import MissingStepError

import argparse
import json
import re
import shutil

import numpy as np
import pytest

from mmsnap_graph.app.commands import monitor as monitor_command
from mmsnap_graph.errors import ValidationError
from mmsnap_graph.io import write_recording
from mmsnap_graph.sim import simulate_recording
from mmsnap_graph.sim.bump import simulate_bumped_recording
from mmsnap_graph.sim import CLEAN, SimulationOptions
from _cli import noise_block, store_partial_noise


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="mmsnap")
    monitor_command.register(parser.add_subparsers(dest="command"))
    return parser


def _run(argv: list[str]) -> int:
    args = _parser().parse_args(["monitor", *argv])
    return args.func(args)


@pytest.fixture(scope="module")
def bumped_path(tmp_path_factory):
    rec = simulate_bumped_recording("C", "random", physics=None, node="S2", bump=(0.0, 0.0, np.deg2rad(2.0)),
                                    bump_time_s=45.0, n_frames=540, seed=3)
    path = tmp_path_factory.mktemp("monitor") / "bumped.h5"
    write_recording(path, rec)
    return path, rec


def test_monitor_reports_the_change_and_the_new_pose(bumped_path, tmp_path, capsys):
    path, rec = bumped_path
    out_json = tmp_path / "monitor.json"
    assert _run([str(path), "--json-out", str(out_json)]) == 0
    out = capsys.readouterr().out
    assert "change: S2 moved at t=" in out and "S2 new pose from frames" in out
    data = json.loads(out_json.read_text())
    assert data["node_order"] == ["S1", "S2"] and data["n_frames"] == 540
    (change,) = data["changes"]
    assert change["node"] == "S2" and change["statistic"] >= data["threshold"]
    assert 0 <= change["detection_time_s"] - rec.metadata["bump_time_s"] <= 20.0
    (recal,) = data["recalibrations"]
    assert recal["success"] and recal["first_frame"] == change["frame"]
    dphi = (recal["pose"][2] - rec.metadata["bumped_phi_rad"] + np.pi) % (2 * np.pi) - np.pi
    assert abs(dphi) < 3 * np.sqrt(recal["covariance"][2][2])
    np.testing.assert_allclose(data["poses"]["S2"], recal["pose"])


def test_monitor_options_poses_sigmas_threshold(bumped_path, tmp_path, capsys):
    path, _ = bumped_path
    poses = tmp_path / "cal.json"
    poses.write_text(json.dumps({"node_order": ["S1", "S2"], "nodes": {
        "S1": {"pose": [0.0, 0.0, 0.0]}, "S2": {"pose": [0.0, 7.0, float(np.pi)]}}}))
    # an absurd threshold: no change; the sigmas are echoed
    assert _run([str(path), "--poses", str(poses), "--sigmas", "0.06", "0.09", "0.1",
                 "--threshold", "1e9"]) == 0
    out = capsys.readouterr().out
    assert "no change detected" in out and "range 0.06 m, omega 0.09 rad" in out


def test_monitor_clean_recording_and_errors(tmp_path, capsys):
    clean = simulate_recording("C", "random", SimulationOptions(physics=None, known_poses=True),
                               levels=("centroids",), n_frames=300, seed=8)
    path = tmp_path / "clean.h5"
    write_recording(path, clean)
    assert _run([str(path)]) == 0
    assert "no change detected" in capsys.readouterr().out
    unknown = tmp_path / "unknown.h5"
    write_recording(unknown, simulate_recording("C", options=CLEAN, levels=("centroids",),
                                                n_frames=30, seed=8))
    with pytest.raises(MissingStepError, match="no pose"):  # exit 1, as `mmsnap fuse`
        _run([str(unknown)])


def test_monitor_json_prints_the_result_alone(bumped_path, tmp_path, capsys):
    """``--json`` prints (stdout holds the JSON alone, the words go to
    stderr); ``--json-out`` writes the same to a file, as on every verb."""
    path, _ = bumped_path
    out_json = tmp_path / "m.json"
    assert _run([str(path), "--json", "--json-out", str(out_json), "--no-progress"]) == 0
    captured = capsys.readouterr()
    printed = json.loads(captured.out)
    assert printed == json.loads(out_json.read_text())
    assert printed["changes"][0]["node"] == "S2"
    assert f"wrote {out_json}" in captured.err and "change: S2" not in captured.out


def test_monitor_prints_the_stored_noise_one_short_line_per_node(recording_b_file, tmp_path,
                                                                 capsys):
    path = shutil.copy(recording_b_file, tmp_path / "rec.h5")
    store_partial_noise(path)
    assert _run([str(path)]) == 0
    out = capsys.readouterr().out
    block = noise_block(out)
    pooled = out.splitlines()[out.splitlines().index(block[-1]) + 1]
    assert pooled == "  one noise for every node (pooled): range 0.0552 m  omega 0.08 rad  Doppler 0.1 m/s"


def test_monitor_warns_of_a_pose_far_from_its_nominal_pose(bumped_path, tmp_path, capsys):
    """S2 of configuration C is at (0, 7) m, heading 180 deg; a nominal
    heading of 90 (the boresight's of a node at heading 0?) is reported with
    its likely cause, the true one is not."""
    import dataclasses
    import warnings

    from mmsnap_graph.errors import MmsnapWarning
    from mmsnap_graph.evaluation.nominal import nominal_metadata

    _, rec = bumped_path
    for s2_deg, expected in ((90.0, 1), (180.0, 0)):
        md = {**rec.metadata, **nominal_metadata("S1", [0, 0, 0], "pose"),
              **nominal_metadata("S2", [0, 7, np.deg2rad(s2_deg)], "pose")}
        path = tmp_path / f"nominal_{s2_deg:.0f}.h5"
        write_recording(path, dataclasses.replace(rec, metadata=md))
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", MmsnapWarning)
            assert _run([str(path), "--poses", str(_true_poses_json(rec, tmp_path))]) == 0
        texts = [str(w.message) for w in caught if issubclass(w.category, MmsnapWarning)]
        assert len(texts) == expected, texts
        if expected:
            assert re.match(r"S2 was calibrated 0\.\d\d m and \+9\d\.\d deg from its nominal "
                            r"pose \(--pose: x 0\.00 m, y 7\.00 m, heading 90\.0 deg in S1's "
                            r"frame\): the headings differ by about 90 deg", texts[0]), texts
    capsys.readouterr()


def _true_poses_json(rec, tmp_path):
    path = tmp_path / "true.json"
    path.write_text(json.dumps({"nodes": {n: {"pose": list(map(float, p))}
                                          for n, p in rec.truth.node_poses.items()}}))
    return path
