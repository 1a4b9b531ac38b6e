"""Fusing a whole recording (mmsnap_graph.fusion.recording.sequence) and ``mmsnap fuse``."""

import json

import h5py
import numpy as np
import pytest

from mmsnap_graph.fusion import FusionOptions
from mmsnap_graph.data.noise import GaussianPrior, MeasurementNoise
from mmsnap_graph.data.results import Status
from mmsnap_graph.app.cli import main
from mmsnap_graph.errors import CalibrationError, FileFormatError, ValidationError
from mmsnap_graph.evaluation import state_errors
from mmsnap_graph.io import read_recording, write_recording
from mmsnap_graph.fusion.solvers.gtsam_graph import fuse_frame
from mmsnap_graph.fusion.recording.sequence import fuse_recording, recording_poses
from mmsnap_graph.io.calibration import load_calibration_poses
from mmsnap_graph.io.fused import read_fused, write_fused
from mmsnap_graph.sim import simulate_recording
from mmsnap_graph.sim import SimulationOptions


@pytest.fixture
def recordings(two_target_recordings):
    """Two walking targets, 10 % missed centroids, per configuration (conftest)."""
    return two_target_recordings


@pytest.mark.parametrize("net", ["A", "B"])
@pytest.mark.parametrize("mode", ["map", "ml"])
def test_batch_and_gtsam_agree_on_every_frame(recordings, net, mode):
    rec = recordings[net]
    fb = fuse_recording(rec, mode=mode, options=FusionOptions(solver="vectorized"))
    fg = fuse_recording(rec, mode=mode, options=FusionOptions(solver="gtsam"))
    np.testing.assert_array_equal(fb.frame, fg.frame)
    np.testing.assert_array_equal(fb.success, fg.success)
    # Both solvers report the same Status codes (carried by the results).
    np.testing.assert_array_equal(fb.status, fg.status)
    ok = fb.success
    np.testing.assert_allclose(fb.state[ok], fg.state[ok], atol=1e-6)
    np.testing.assert_allclose(fb.covariance[ok], fg.covariance[ok], atol=1e-6)
    # Frames seen by one node only: fused with what there is (MAP), or
    # flagged (ML, 3 measurements for 4 unknowns).
    single = fb.observed.sum(axis=1) == 1
    assert single.any()
    assert fb.success[single].all() if mode == "map" else not fb.success[single].any()


def test_configuration_c_batch_at_least_as_converged_as_gtsam(recordings):
    """Near the line through both radars GTSAM's LM stops in a flat valley a
    few 1e-6 short of the minimum; the batch solver's cost is never higher."""
    rec = recordings["C"]
    fb = fuse_recording(rec, options=FusionOptions(solver="vectorized"))
    fg = fuse_recording(rec, options=FusionOptions(solver="gtsam"))
    np.testing.assert_array_equal(fb.success, fg.success)
    ok = fb.success
    assert np.all(fb.final_cost[ok] <= fg.final_cost[ok] + 1e-12 * np.maximum(1, fg.final_cost[ok]))
    close = np.all(np.abs(fb.state - fg.state) <= 1e-6, axis=1)
    assert close[ok].mean() > 0.9
    np.testing.assert_allclose(fb.state[ok], fg.state[ok], atol=1e-4)


def test_targets_are_recovered_with_their_labels(recordings):
    rec = recordings["B"]
    fused = fuse_recording(rec)
    assert set(np.unique(fused.label)) <= {-1, 0, 1}
    assert (fused.label >= 0).mean() > 0.9
    for label in (0, 1):
        rows = fused.rows_of_label(label)
        rows = rows[fused.success[rows]]
        _, truth = rec.truth.target(label)
        err = state_errors(fused.state[rows], truth[fused.frame[rows]])
        # Paper Table III, configuration B: 0.14-0.17 m and 0.27-0.34 m/s.
        assert err.position_rmse_m < 0.3 and err.velocity_rmse_mps < 0.6


def test_grid_covariance_matches_fuse_frame(recordings):
    rec = recordings["B"]
    fused = fuse_recording(rec, options=FusionOptions(covariance="grid", grid_points_per_axis=7))
    rows = np.flatnonzero(fused.success)[:4]
    obs = fused.observed
    for i in rows:
        z = np.zeros((2, 3))
        for n, name in enumerate(fused.node_names):
            if obs[i, n]:
                z[n] = rec.nodes[name].centroids.measurements[fused.detection_index[i, n]]
        ref = fuse_frame(fused.node_poses,
                         z,
                         observed=obs[i],
                         options=FusionOptions(covariance="grid", grid_points_per_axis=7))
        np.testing.assert_allclose(fused.covariance[i], ref.grid_covariance, rtol=1e-4, atol=1e-7)
        np.testing.assert_allclose(fused.laplace_covariance[i], ref.covariance, atol=1e-6)


def test_write_and_read_fused_round_trip(recordings, tmp_path):
    rec = recordings["A"]
    path = write_recording(tmp_path / "rec.h5", rec)
    fused = fuse_recording(rec, mode="ml")
    write_fused(path, fused)
    back = read_fused(path)
    for name in ("frame", "target", "label", "detection_index", "observed", "success", "status",
                 "iterations"):
        np.testing.assert_array_equal(getattr(back, name), getattr(fused, name))
    for name in ("state", "covariance", "laplace_covariance", "final_cost", "degeneracy", "node_poses"):
        np.testing.assert_array_equal(getattr(back, name), getattr(fused, name))
    assert back.mode == "ml" and back.prior_mean is None and list(back.message) == list(fused.message)
    # ML frames seen by one node are singular: code 2 of the file contract.
    assert set(np.unique(back.status)) <= {Status.OK, Status.SINGULAR}
    assert (back.status == Status.SINGULAR).any()
    with h5py.File(path, "r") as f:
        codes = json.loads(f["fused"].attrs["status_messages"])
    assert sorted(int(c) for c in codes) == [0, 1, 2, 3, 4, 5, 9, 10, 11, 12]
    # The recording itself is intact, and a second write replaces /fused.
    assert read_recording(path).node_names == rec.node_names
    write_fused(path, fuse_recording(rec))
    assert read_fused(path).mode == "map"


def test_write_fused_to_a_new_file_leaves_the_original(recordings, tmp_path):
    path = write_recording(tmp_path / "rec.h5", recordings["A"])
    out = write_fused(path, fuse_recording(recordings["A"]), output=tmp_path / "out.h5")
    with h5py.File(path, "r") as f:
        assert "fused" not in f
    assert len(read_fused(out)) > 0


def test_fused_errors(tmp_path, recordings):
    with pytest.raises(FileFormatError, match="does not exist"):
        read_fused(tmp_path / "nope.h5")
    path = write_recording(tmp_path / "rec.h5", recordings["A"])
    with pytest.raises(FileFormatError, match="has no /fused group"):
        read_fused(path)
    write_fused(path, fuse_recording(recordings["A"]))
    with h5py.File(path, "r+") as f:
        del f["fused/covariance"]
    with pytest.raises(FileFormatError, match="/fused/covariance is missing"):
        read_fused(path)
    with pytest.raises(FileFormatError, match="does not exist"):
        write_fused(tmp_path / "nope.h5", fuse_recording(recordings["A"]))


def test_calibration_json_and_pose_sources(tmp_path, recordings):
    rec = recordings["C"]
    calib = {"reference": "S1", "nodes": {"S1": {"pose": [0, 0, 0], "covariance": np.eye(3).tolist()},
                                          "S2": {"pose": [0.1, 6.9, np.pi - 0.02]}}}
    path = tmp_path / "calib.json"
    path.write_text(json.dumps(calib))
    poses = load_calibration_poses(path)
    np.testing.assert_array_equal(recording_poses(rec, poses)[1], [0.1, 6.9, np.pi - 0.02])
    np.testing.assert_array_equal(recording_poses(rec), np.stack([rec.nodes[n].pose for n in rec.node_names]))
    fused = fuse_recording(rec, node_poses=poses)
    np.testing.assert_array_equal(fused.node_poses[1], [0.1, 6.9, np.pi - 0.02])


@pytest.mark.parametrize(
    "content, match",
    [
        ("{", "is not readable calibration JSON"),
        (json.dumps({"nodes": {}}), "missing or empty 'nodes'"),
        (json.dumps({"nodes": {"S1": {}}}), r"nodes\['S1'\] has no 'pose'"),
        (json.dumps({"nodes": {"S1": {"pose": [0, 0]}}}), r"nodes\['S1'\].pose must be 3 finite"),
        (json.dumps({"nodes": {"S1": {"pose": ["a", 0, 0]}}}), "is not numeric"),
    ],
)
def test_calibration_json_errors(tmp_path, content, match):
    path = tmp_path / "c.json"
    path.write_text(content)
    with pytest.raises(CalibrationError, match=match):
        load_calibration_poses(path)


def test_missing_calibration_file_and_poses(tmp_path, recordings):
    with pytest.raises(CalibrationError, match="does not exist"):
        load_calibration_poses(tmp_path / "none.json")
    rec = recordings["A"]
    with pytest.raises(CalibrationError, match="no pose for node 'S2'"):
        recording_poses(rec, {"S1": [0, 0, 0]})
    import dataclasses

    bare = rec.with_node(dataclasses.replace(rec.nodes["S2"], pose=None))
    with pytest.raises(CalibrationError, match="node 'S2' has no pose in the recording"):
        fuse_recording(bare)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(mode="bayes"), "mode must be 'map' or 'ml'"),
        (dict(options=dict(covariance="exact")), "covariance must be 'laplace', 'grid', 'both'"),
        (dict(options=dict(covariance="both")), "options.covariance must be 'laplace' or 'grid'"),
        (dict(options=dict(solver="scipy")), "solver must be 'gtsam' or 'vectorized' or 'scalar'"),
        (dict(options=dict(solver="batch")), "'batch' is now called 'vectorized'"),
        (dict(options=dict(solver="scalar")), "options.solver must be 'vectorized' or 'gtsam'"),
        (dict(options=dict(source="cube")), "source must be 'centroids', 'point_cloud'"),
        (dict(mode="ml", prior=GaussianPrior(mean=[0, 0, 0, 0])), "mode='ml' takes no prior"),
        (dict(options=dict(block_rows=0)), "block_rows=0 must be an integer >= 1"),
        (dict(options=dict(source="point_cloud")), "no node of the recording has point_cloud"),
        (dict(options="laplace"), "options must be a FusionOptions, got str"),
    ],
)
def test_fuse_recording_invalid_arguments(recordings, kwargs, match):
    with pytest.raises(ValidationError, match=match):
        if isinstance(kwargs.get("options"), dict):
            kwargs = dict(kwargs, options=FusionOptions(**kwargs["options"]))
        fuse_recording(recordings["A"], **kwargs)


def test_cli_fuse_writes_the_fused_group(tmp_path, recordings, capsys):
    rec = recordings["B"]
    path = write_recording(tmp_path / "rec.h5", rec)
    calib = tmp_path / "calib.json"
    calib.write_text(json.dumps({"nodes": {n: {"pose": rec.nodes[n].pose.tolist()} for n in rec.node_names}}))
    assert main(["fuse", str(path), "--calibration", str(calib), "--mode", "ml", "--no-progress"]) == 0
    assert "wrote" in capsys.readouterr().out
    fused = read_fused(path)
    assert fused.mode == "ml" and fused.covariance_method == "laplace" and fused.solver == "vectorized"
    from mmsnap_graph.fusion.recording.room import DEFAULT_BODY_M, screen_room
    # The CLI's default: the robust gate, then one target per body.
    ref = screen_room(fuse_recording(rec, mode="ml", robust="gate"), body_m=DEFAULT_BODY_M)[0]
    np.testing.assert_allclose(fused.state[fused.success], ref.state[ref.success], atol=1e-12)
    out = tmp_path / "copy.h5"
    assert main(["fuse", str(path), "-o", str(out), "--no-progress"]) == 0
    assert read_fused(out).mode == "map" and read_fused(path).mode == "ml"
    assert main(["fuse", str(path), "--calibration", str(tmp_path / "none.json")]) == 1
    assert "does not exist" in capsys.readouterr().err


def test_cli_fuse_takes_measurement_sigmas(tmp_path, recordings, capsys):
    rec = recordings["B"]
    path = write_recording(tmp_path / "rec.h5", rec)
    assert main(["fuse", str(path), "--sigmas", "0.05", "0.08", "0.1", "--no-progress"]) == 0
    fused = read_fused(path)
    np.testing.assert_allclose(fused.noise_sigmas, [0.05, 0.08, 0.1])
    ref = fuse_recording(rec, noise=MeasurementNoise(range_m=0.05, omega_rad=0.08,
                                                             doppler_mps=0.1))
    np.testing.assert_allclose(fused.covariance[fused.success], ref.covariance[ref.success],
                               atol=1e-12)
    assert main(["fuse", str(path), "--sigmas", "0.05", "-1", "0.1", "--no-progress"]) == 2
    assert "omega_rad must be finite and > 0" in capsys.readouterr().err


def test_vectorized_grouping_equals_frame_by_frame_association(recordings):
    """The fast path of group_detections (one detection per node, one gate)
    gives what associate_frame gives frame by frame."""
    from mmsnap_graph.fusion.association import associate_frame
    from mmsnap_graph.fusion.recording.sequence import group_detections

    rec = simulate_recording("A", "random",
                             SimulationOptions(physics=None, known_poses=True, centroid_p_miss=0.2),
                             levels=("centroids",), n_frames=80, seed=2)
    import dataclasses

    from mmsnap_graph.data.recording import Detections

    # A false alarm far from the target in frame 5 (S2): that frame takes the
    # per-frame path, the others the vectorized one.
    c2 = rec.nodes["S2"].centroids
    extra = Detections(frame=np.append(c2.frame, 5), range_m=np.append(c2.range_m, 9.0),
                       omega_rad=np.append(c2.omega_rad, 2.5), doppler_mps=np.append(c2.doppler_mps, 0.0))
    rec = rec.with_node(dataclasses.replace(rec.nodes["S2"], centroids=extra))
    poses = recording_poses(rec)
    groups = group_detections(rec, poses, MeasurementNoise())
    assert np.count_nonzero(groups.frame == 5) == 2
    cents = [rec.nodes[n].centroids for n in rec.node_names]
    rows = []
    for f in np.unique(np.concatenate([c.frame for c in cents])):
        idx = [np.flatnonzero(c.frame == f) for c in cents]
        a = associate_frame([c.measurements[i] for c, i in zip(cents, idx)], poses, MeasurementNoise())
        for g, members in enumerate(a.members):
            rows.append((f, g, *[idx[n][m] if m >= 0 else -1 for n, m in enumerate(members)]))
    expected = np.array(rows)
    np.testing.assert_array_equal(groups.frame, expected[:, 0])
    np.testing.assert_array_equal(groups.target, expected[:, 1])
    np.testing.assert_array_equal(groups.detection_index, expected[:, 2:])
