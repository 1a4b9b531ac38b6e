"""``mmsnap calibrate`` and the recording-level API, on simulated recordings."""

from __future__ import annotations

import dataclasses
import json

import h5py
import numpy as np
import pytest

from mmsnap_graph.calibration import (
    calibrate_recording,
    joint_calibration,
    pose_tangent_error,
    residual_noise,
)
from mmsnap_graph.app.cli import main
from mmsnap_graph.data.noise import MeasurementNoise
from mmsnap_graph.errors import CalibrationError
from mmsnap_graph.io import read_recording, write_recording
from mmsnap_graph.data.recording import NodeData, Recording, Tracks


@pytest.fixture
def rec_c(recording_c_random):
    return recording_c_random


def _shift(rec, name, lag):
    node = rec.nodes[name]
    c = dataclasses.replace(node.centroids, frame=node.centroids.frame + lag)
    return rec.with_node(dataclasses.replace(node, centroids=c))


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


def test_lag_is_found_and_used(rec_c):
    cal = calibrate_recording(_shift(rec_c, "S2", 1))
    assert cal.lag_frames == {"S1": 0, "S2": 1}
    assert cal.method == "joint"
    err = pose_tangent_error(cal.poses["S2"], rec_c.truth.node_poses["S2"])
    assert np.hypot(err[0], err[1]) < 0.1


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


def test_tracks_are_preferred_and_joint_needs_centroids(rec_c):
    """Tracks (here: the truth in each local frame plus 5 cm noise) are used
    when present; without centroids the joint step is skipped, or raises when
    required."""
    rng = np.random.default_rng(0)
    fr, st = rec_c.truth.target(0)
    nodes = {}
    for n in ("S1", "S2"):
        from factors.models import global_to_local

        local = global_to_local(st[:, :2], rec_c.truth.node_poses[n]) + rng.normal(
            size=(fr.size, 2)) * 0.05
        state = np.column_stack([local, np.zeros((fr.size, 2))])
        nodes[n] = NodeData(name=n, tracks=Tracks(frame=fr, track_id=np.full(fr.size, 4),
                                                  state=state,
                                                  covariance=np.tile(np.eye(4), (fr.size, 1, 1))))
    rec = Recording(frame_period_s=rec_c.frame_period_s, nodes=nodes)
    cal = calibrate_recording(rec)
    assert cal.source == "tracks" and cal.method == "pose_graph"
    assert "joint refinement skipped" in cal.message
    err = pose_tangent_error(cal.poses["S2"], rec_c.truth.node_poses["S2"])
    assert np.hypot(err[0], err[1]) < 0.05
    with pytest.raises(CalibrationError, match="needs centroids of a common target"):
        calibrate_recording(rec, method="joint")


@pytest.mark.slow
def test_noise_is_estimated_without_metadata(rec_c):
    rec = dataclasses.replace(rec_c, metadata={})
    cal = calibrate_recording(rec)
    assert "sigmas estimated from residuals" in cal.message
    meta = rec_c.metadata
    truth = np.array([meta["centroid_range_std_m"], meta["centroid_omega_std_rad"],
                      meta["centroid_doppler_std_mps"]])
    dets = {n: rec.nodes[n].centroids for n in rec.node_names}
    est = MeasurementNoise(range_m=0.035, omega_rad=0.1, doppler_mps=0.18)
    for _ in range(2):  # as calibrate_recording does
        first = joint_calibration(dets, noise=est)  # no motion factors
        est = residual_noise(first, dets, noise=est)
    # range and omega: leverage-corrected, within 15% of the truth (300
    # frames x 2 nodes, ~300 residual dof per component); the Doppler of two
    # nodes without motion factors is not identifiable and keeps its value
    np.testing.assert_allclose(est.sigmas[:2], truth[:2], rtol=0.15)
    assert est.doppler_mps == 0.18
