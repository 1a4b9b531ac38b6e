"""Fusing a recording file window by window (issue 13: long recordings are
read in chunks; ``mmsnap fuse`` goes through :func:`fuse_file`)."""

from __future__ import annotations

import dataclasses

import h5py
import numpy as np
import pytest

from _scenes import small_room_image
from mmsnap_graph.app import chunked_fuse
from mmsnap_graph.app.chunked_fuse import fuse_file
from mmsnap_graph.app.cli import main
from mmsnap_graph.data.noise import MeasurementNoise
from mmsnap_graph.data.recording import Detections, Recording
from mmsnap_graph.errors import FileFormatError, ValidationError
from mmsnap_graph.fusion.recording.sequence import fuse_recording, fuse_recording_rows
from mmsnap_graph.fusion.options import NetworkCalibration
from mmsnap_graph.io import read_fused, read_recording, write_recording
from mmsnap_graph.io.chunks import open_detection_windows
from _fusion import config

EXACT = ("frame", "target", "label", "detection_index", "observed", "success", "status",
         "track_id")
CLOSE = ("state", "covariance", "laplace_covariance", "degeneracy", "information",
         "information_vector", "time_s")


@pytest.fixture(scope="module")
def good(tmp_path_factory):
    path = tmp_path_factory.mktemp("chunked") / "good.h5"
    assert main(["simulate", "--model", "clean", "-c", "B", "-t", "random", "-n", "150", "-l", "centroids",
                 "--targets", "2", "--seed", "3", "--known-poses", "-o", str(path),
                 "--no-progress"]) == 0
    return path


@pytest.fixture(scope="module")
def reference(good):
    return fuse_recording(read_recording(good), config(), progress=False)


def assert_same(got, ref):
    for k in EXACT:
        np.testing.assert_array_equal(getattr(got, k), getattr(ref, k), err_msg=k)
    for k in CLOSE:
        np.testing.assert_allclose(getattr(got, k), getattr(ref, k), rtol=0, atol=1e-9,
                                   equal_nan=True, err_msg=k)
    assert list(got.message) == list(ref.message)
    assert got.mode == ref.mode and got.node_names == ref.node_names
    np.testing.assert_array_equal(got.node_poses, ref.node_poses)


@pytest.mark.parametrize("window", [1, 7, 64, 100_000])
def test_fuse_file_equals_fuse_recording(good, reference, tmp_path, window):
    out = tmp_path / "out.h5"
    summary = fuse_file(good, config(walls=True), output=out, window_frames=window, progress=False)
    got = read_fused(out)
    assert_same(got, reference)
    assert summary.n_rows == len(reference) and summary.path == out
    assert summary.n_success == int(reference.success.sum())
    assert summary.n_frames == np.unique(reference.frame).size
    frames = reference.frame.max() - reference.frame.min() + 1
    assert summary.n_windows == -(-frames // window)  # no gap in this recording


def test_detection_indices_are_rows_of_the_file(good, tmp_path):
    out = tmp_path / "out.h5"
    fuse_file(good, config(walls=True), output=out, window_frames=9, progress=False)
    fused, rec = read_fused(out), read_recording(good)
    for n, name in enumerate(rec.node_names):
        c = rec.nodes[name].centroids
        seen = fused.detection_index[:, n] >= 0
        np.testing.assert_array_equal(c.frame[fused.detection_index[seen, n]], fused.frame[seen])


def test_unsorted_rows_are_read_by_frame(good, tmp_path):
    rec = read_recording(good)
    perm = np.random.default_rng(0).permutation(len(rec.nodes["S2"].centroids))
    c = rec.nodes["S2"].centroids
    shuffled = Detections(frame=c.frame[perm], range_m=c.range_m[perm],
                          omega_rad=c.omega_rad[perm], doppler_mps=c.doppler_mps[perm],
                          snr_db=None if c.snr_db is None else c.snr_db[perm],
                          target_id=None if c.target_id is None else c.target_id[perm])
    nodes = dict(rec.nodes, S2=dataclasses.replace(rec.nodes["S2"], centroids=shuffled))
    path = write_recording(tmp_path / "shuffled.h5",
                           Recording(frame_period_s=rec.frame_period_s, nodes=nodes))
    ref = fuse_recording(read_recording(path), config(), progress=False)
    fuse_file(path, config(walls=True), window_frames=11, progress=False)
    assert_same(read_fused(path), ref)


def test_each_window_holds_only_its_frames(good, monkeypatch, tmp_path):
    seen = []

    def spy(recording, *a, **kw):
        frames = np.concatenate([recording.nodes[n].centroids.frame for n in recording.node_names])
        seen.append((frames.min(), frames.max()) if frames.size else None)
        return fuse_recording_rows(recording, *a, **kw)

    monkeypatch.setattr(chunked_fuse, "fuse_recording_rows", spy)
    fuse_file(good, config(walls=True), output=tmp_path / "o.h5", window_frames=20, progress=False)
    spans = [s for s in seen if s is not None]
    assert len(spans) >= 7 and all(hi - lo < 20 for lo, hi in spans)
    index = open_detection_windows(good)
    rec, rows = index.read(40, 60)
    for name in rec.node_names:
        f = rec.nodes[name].centroids.frame
        assert np.all((f >= 40) & (f < 60)) and rows[name].size == f.size


def test_an_error_in_a_late_window_leaves_the_file_unchanged(good, tmp_path, monkeypatch):
    path = tmp_path / "rec.h5"
    path.write_bytes(good.read_bytes())
    fuse_file(path, config(walls=True), window_frames=50, progress=False)
    before = path.read_bytes()
    calls = []

    def failing(recording, *a, **kw):
        calls.append(1)
        if len(calls) == 3:
            raise FileFormatError("boom")
        return fuse_recording_rows(recording, *a, **kw)

    monkeypatch.setattr(chunked_fuse, "fuse_recording_rows", failing)
    with pytest.raises(FileFormatError, match="boom"):
        fuse_file(path, config(walls=True), window_frames=10, progress=False)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rec.h5"]


def test_a_non_finite_value_in_a_window_is_a_format_error_naming_it(good, tmp_path):
    path = tmp_path / "nan.h5"
    path.write_bytes(good.read_bytes())
    with h5py.File(path, "r+") as f:
        f["nodes/S2/centroids/range_m"][120] = np.nan
    before = path.read_bytes()
    with pytest.raises(FileFormatError, match=r"nan\.h5.*S2/centroids/range_m.*row 120"):
        fuse_file(path, config(walls=True), window_frames=16, progress=False)
    assert path.read_bytes() == before
    assert main(["fuse", str(path), "--no-progress"]) == 1


def test_gaps_without_detections_are_skipped(good, tmp_path):
    rec = read_recording(good)
    nodes = {}
    for name, node in rec.nodes.items():
        c = node.centroids
        keep = (c.frame < 30) | (c.frame >= 90)
        nodes[name] = dataclasses.replace(node, centroids=Detections(
            frame=c.frame[keep], range_m=c.range_m[keep], omega_rad=c.omega_rad[keep],
            doppler_mps=c.doppler_mps[keep]))
    path = write_recording(tmp_path / "gap.h5",
                           Recording(frame_period_s=rec.frame_period_s, nodes=nodes))
    ref = fuse_recording(read_recording(path), config(), progress=False)
    summary = fuse_file(path, config(walls=True), window_frames=10, progress=False)
    assert_same(read_fused(path), ref)
    frames = np.unique(ref.frame)
    starts = np.arange(frames.min(), frames.max() + 1, 10)
    with_data = {int(np.searchsorted(starts, f, side="right")) - 1 for f in frames}
    assert summary.n_windows == len(with_data) < len(starts)  # the gap's windows are skipped


def test_a_recording_without_detections_is_refused_as_by_fuse_recording(good, tmp_path):
    rec = read_recording(good)
    empty = Detections(frame=np.zeros(0, int), range_m=[], omega_rad=[], doppler_mps=[])
    nodes = {n: dataclasses.replace(node, centroids=empty) for n, node in rec.nodes.items()}
    path = write_recording(tmp_path / "empty.h5",
                           Recording(frame_period_s=rec.frame_period_s, nodes=nodes))
    with pytest.raises(ValidationError, match="nothing to fuse"):
        fuse_recording(read_recording(path), config(), progress=False)
    with pytest.raises(ValidationError, match="nothing to fuse"):
        fuse_file(path, config(walls=True), progress=False)
    assert "fused" not in h5py.File(path, "r")


@pytest.mark.parametrize("window", [0, 2.5, True, "10"])
def test_window_frames_must_be_a_positive_integer(good, window):
    with pytest.raises(ValidationError, match="window_frames"):
        fuse_file(good, config(walls=True), window_frames=window)


def test_the_calibration_is_one_network_calibration(good):
    with pytest.raises(ValidationError, match="calibration must be a NetworkCalibration"):
        fuse_file(good, config(walls=True), calibration={"time_offset_s": {"S2": 0.1}}, progress=False)


def test_the_cli_writes_what_fuse_file_writes(good, tmp_path, capsys):
    """The CLI's default is the robust gate with the motion check, then one
    target per body (fusion.recording.room), then the person ids of the rows
    left (the tracker is the last step)."""
    from mmsnap_graph.fusion.recording.room import DEFAULT_BODY_M, screen_room
    from mmsnap_graph.tracking.person_ids import assign_person_ids
    reference = assign_person_ids(screen_room(
        fuse_recording(read_recording(good), config(robust="gate"), progress=False),
        body_m=DEFAULT_BODY_M)[0])
    out = tmp_path / "cli.h5"
    assert main(["fuse", str(good), "-o", str(out), "--no-progress"]) == 0
    assert f"fused {len(reference)} targets" in capsys.readouterr().out
    assert_same(read_fused(out), reference)


@pytest.mark.parametrize("window", [1, 7, 100_000])
def test_clock_offsets_read_each_node_shifted(good, tmp_path, window):
    """With clock offsets each node's window is read shifted by its whole
    frames: any window size gives fuse_recording's rows (S2 2.4 frames
    late, S1 on the reference clock)."""
    offsets = {"S2": -2.4 * 0.15}
    ref = fuse_recording(read_recording(good), config(), progress=False, calibration=NetworkCalibration(time_offset_s=offsets))
    out = tmp_path / "off.h5"
    summary = fuse_file(good, config(walls=True), output=out, window_frames=window, progress=False, calibration=NetworkCalibration(time_offset_s=offsets))
    got = read_fused(out)
    assert summary.n_rows == len(ref)
    for k in EXACT:
        np.testing.assert_array_equal(getattr(got, k), getattr(ref, k), err_msg=k)
    # The batch solver's stopping point may differ by an iteration between
    # windows of different sizes (1e-9 m here).
    for k in ("state", "covariance", "time_s"):
        np.testing.assert_allclose(getattr(got, k), getattr(ref, k), rtol=0, atol=1e-7,
                                   err_msg=k)


@pytest.mark.parametrize("window", [7, 100_000])
def test_the_coverage_check_judges_each_window_by_the_whole_file(tmp_path, window):
    # A node's reach is the farthest of all its detections in the file (the
    # point cloud's static reflector here), not of the window's own centroids.
    rec, _, image = small_room_image()
    path = tmp_path / "room.h5"
    write_recording(path, rec)
    noise = MeasurementNoise(range_m=0.02, omega_rad=0.01, doppler_mps=0.05)
    ref = fuse_recording(read_recording(path), config(robust="gate"), noise=noise,
                         progress=False)
    fuse_file(path, config(robust="gate"), output=tmp_path / "out.h5", window_frames=window,
              progress=False, noise=noise)
    got = read_fused(tmp_path / "out.h5")
    assert_same(got, ref)
    at_image = np.hypot(*(got.state[:, :2] - image[got.frame, :2]).T) < 0.5
    assert at_image.sum() == 40 and not got.success[at_image].any()
