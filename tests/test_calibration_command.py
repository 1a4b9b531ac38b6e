"""``mmsnap calibrate`` on simulated recordings (the library calls: tests/calibration/)."""

from __future__ import annotations

import dataclasses
import json

import h5py
import numpy as np
import pytest

from mmsnap_graph.app.cli import main
from mmsnap_graph.calibration import pose_tangent_error
from mmsnap_graph.data.recording import Recording
from mmsnap_graph.io import read_recording, write_recording


@pytest.fixture
def rec_c(recording_c_random):
    return recording_c_random


def test_calibrate_command_writes_json_poses_and_group(rec_c, tmp_path, capsys):
    path = tmp_path / "rec.h5"
    write_recording(path, rec_c)
    assert main(["calibrate", str(path)]) == 0
    out = capsys.readouterr().out
    assert "phi_deg" in out and "method joint" in out
    truth = rec_c.truth.node_poses["S2"]
    data = json.loads((tmp_path / "rec.calibration.json").read_text())
    assert data["reference"] == "S1" and data["unreachable"] == []
    assert data["nodes"]["S1"]["pose"] == [0.0, 0.0, 0.0]
    s2 = data["nodes"]["S2"]
    assert np.array(s2["covariance"]).shape == (3, 3)
    err = pose_tangent_error(s2["pose"], truth)
    assert np.hypot(err[0], err[1]) < 0.1 and abs(err[2]) < np.radians(1.0)
    # printed in degrees: S2 faces S1, phi ~ +-180
    row = next(line for line in out.splitlines() if line.startswith("S2"))
    assert abs(abs(float(row.split()[3])) - 180.0) < 1.0
    back = read_recording(path)
    np.testing.assert_allclose(back.nodes["S2"].pose, s2["pose"])
    np.testing.assert_allclose(back.nodes["S1"].pose, np.zeros(3))
    assert len(back.nodes["S2"].centroids) == len(rec_c.nodes["S2"].centroids)
    with h5py.File(path, "r") as f:
        g = f["calibration"]
        assert g.attrs["reference"] == "S1" and g.attrs["method"] == "joint"
        assert list(g["node_name"].asstr()[()]) == ["S1", "S2"]
        np.testing.assert_allclose(g["pose"][1], s2["pose"])
        assert g["covariance"].shape == (2, 3, 3)
        assert g["edges/rmse_m"].shape == (1,) and 0 < g["edges/rmse_m"][0] < 0.5
        assert json.loads(g.attrs["json"])["nodes"]["S2"]["pose"] == s2["pose"]
    # a second run replaces the group
    assert main(["calibrate", str(path), "--method", "pose_graph"]) == 0
    with h5py.File(path, "r") as f:
        assert f["calibration"].attrs["method"] == "pose_graph"


def test_no_write_and_output_copy(rec_c, tmp_path):
    path = tmp_path / "rec.h5"
    write_recording(path, rec_c)
    js = tmp_path / "cal.json"
    assert main(["calibrate", str(path), "--no-write", "--json-out", str(js),
                 "--method", "pose_graph"]) == 0
    assert js.exists()
    assert read_recording(path).nodes["S2"].pose is None
    copy = tmp_path / "copy.h5"
    assert main(["calibrate", str(path), "-o", str(copy), "--method", "pose_graph",
                 "--json-out", str(js), "--overwrite"]) == 0
    assert read_recording(path).nodes["S2"].pose is None
    assert read_recording(copy).nodes["S2"].pose is not None


def test_unreachable_node_is_reported(rec_c, tmp_path, capsys):
    s3 = dataclasses.replace(rec_c.nodes["S2"], name="S3")
    s3 = dataclasses.replace(s3, centroids=dataclasses.replace(
        s3.centroids, frame=s3.centroids.frame + 5000))
    rec = rec_c.with_node(s3)
    path = tmp_path / "rec3.h5"
    write_recording(path, rec)
    assert main(["calibrate", str(path), "--method", "pose_graph"]) == 1
    out = capsys.readouterr().out
    assert "not calibrated (no path to S1)" in out and "INCOMPLETE" in out
    data = json.loads((tmp_path / "rec3.calibration.json").read_text())
    assert data["unreachable"] == ["S3"] and "S3" not in data["nodes"]
    assert read_recording(path).nodes["S3"].pose is None
    with h5py.File(path, "r") as f:
        assert list(f["calibration/calibrated"][()]) == [True, True, False]
        assert np.all(np.isnan(f["calibration/pose"][2]))


def test_single_node_is_a_clean_cli_error(rec_c, tmp_path, capsys):
    rec = Recording(frame_period_s=rec_c.frame_period_s, nodes={"S1": rec_c.nodes["S1"]})
    path = tmp_path / "one.h5"
    write_recording(path, rec)
    assert main(["calibrate", str(path)]) == 1
    assert "at least two nodes" in capsys.readouterr().err
