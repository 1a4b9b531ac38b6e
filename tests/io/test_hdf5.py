"""Round trips and reader errors of the HDF5 recording format (docs/FORMAT.md)."""

from __future__ import annotations

import os
from pathlib import Path
import dataclasses
import itertools

import h5py
import numpy as np
import pytest
from numpy.testing import assert_array_equal
from hypothesis import HealthCheck, given, settings, strategies as st

from mmsnap_graph import (
    Detections,
    FileFormatError,
    NodeData,
    RadarConfig,
    Recording,
    Tracks,
    Truth,
    MmsnapError,
)
from mmsnap_graph.io import (
    FORMAT_NAME,
    iter_cubes,
    read_cube_frames,
    read_recording,
    update_recording,
    write_recording,
)
from mmsnap_graph.sim import CLEAN, simulate_recording
from mmsnap_graph.data.radar_config import TABLE_I
from mmsnap_graph.app.cli import main

SMALL_RADAR = RadarConfig(n_samples=16, n_loops=4, chirp_period_s=20e-6)


def _detections(rng, n, *, optional=True):
    return Detections(
        frame=np.sort(rng.integers(0, 50, n)),
        range_m=rng.uniform(0.5, 10, n),
        omega_rad=rng.uniform(-np.pi, np.pi, n),
        doppler_mps=rng.normal(0, 1, n),
        snr_db=rng.uniform(5, 30, n) if optional else None,
        target_id=rng.integers(-1, 2, n) if optional else None,
    )


def _recording(seed=0, *, n_points=2000, cube_frames=3):
    rng = np.random.default_rng(seed)
    k = 40
    a = rng.normal(size=(k, 4, 4))
    tracks = Tracks(frame=np.arange(k), track_id=rng.integers(0, 3, k),
                    state=rng.normal(size=(k, 4)), covariance=a @ np.swapaxes(a, 1, 2))
    cube = (rng.normal(size=(cube_frames, *SMALL_RADAR.cube_shape))
            + 1j * rng.normal(size=(cube_frames, *SMALL_RADAR.cube_shape))).astype(np.complex64)
    # Node order deliberately not alphabetical: it must round-trip.
    nodes = {
        "S1": NodeData(name="S1", pose=np.zeros(3), radar=SMALL_RADAR, cube=cube,
                       cube_frame=np.arange(10, 10 + cube_frames),
                       point_cloud=_detections(rng, n_points), centroids=_detections(rng, 30),
                       tracks=tracks),
        "Z9": NodeData(name="Z9", centroids=_detections(rng, 25, optional=False)),
        "A0": NodeData(name="A0", pose=[1.0, 2.0, 0.3], radar=SMALL_RADAR),
    }
    truth = Truth(frame=np.repeat(np.arange(20), 2), target_id=np.tile([0, 1], 20),
                  state=rng.normal(size=(40, 4)),
                  node_poses={"S1": np.zeros(3), "Z9": [4.0, 0.0, np.pi / 6]})
    return Recording(frame_period_s=0.15, nodes=nodes, truth=truth,
                     metadata={"configuration": "B", "seed": 7, "snr": 12.5})


def _assert_detections_equal(a, b):
    for name in ("frame", "range_m", "omega_rad", "doppler_mps"):
        assert_array_equal(getattr(a, name), getattr(b, name))
    for name in ("snr_db", "target_id"):
        if getattr(a, name) is None:
            assert getattr(b, name) is None
        else:
            assert_array_equal(getattr(a, name), getattr(b, name))


def _assert_recordings_equal(a, b, *, cubes=True):
    assert a.frame_period_s == b.frame_period_s
    assert a.node_names == b.node_names
    assert a.metadata == b.metadata
    for name in a.node_names:
        na, nb = a.nodes[name], b.nodes[name]
        if na.pose is None:
            assert nb.pose is None
        else:
            assert_array_equal(na.pose, nb.pose)
        assert na.radar == nb.radar
        for level in ("point_cloud", "centroids"):
            if getattr(na, level) is None:
                assert getattr(nb, level) is None
            else:
                _assert_detections_equal(getattr(na, level), getattr(nb, level))
        if na.tracks is None:
            assert nb.tracks is None
        else:
            for f in ("frame", "track_id", "state", "covariance"):
                assert_array_equal(getattr(na.tracks, f), getattr(nb.tracks, f))
        if cubes and na.cube is not None:
            assert nb.cube.dtype == np.complex64
            assert_array_equal(na.cube, nb.cube)
            assert_array_equal(na.cube_frame, nb.cube_frame)
    assert_array_equal(a.truth.frame, b.truth.frame)
    assert_array_equal(a.truth.target_id, b.truth.target_id)
    assert_array_equal(a.truth.state, b.truth.state)
    assert a.truth.node_poses.keys() == b.truth.node_poses.keys()
    for k in a.truth.node_poses:
        assert_array_equal(a.truth.node_poses[k], b.truth.node_poses[k])


def test_round_trip_every_dataset(tmp_path):
    rec = _recording()
    path = write_recording(tmp_path / "r.h5", rec)
    back = read_recording(path)
    _assert_recordings_equal(rec, back)
    assert back.node_names == ["S1", "Z9", "A0"]
    assert back.metadata == {"configuration": "B", "seed": 7, "snr": 12.5}
    # No temporary file left behind.
    assert sorted(os.listdir(tmp_path)) == ["r.h5"]


def test_the_target_model_round_trips_and_defaults_to_people(tmp_path):
    points = dataclasses.replace(_recording(), targets="points")
    path = write_recording(tmp_path / "r.h5", points)
    assert read_recording(path).targets == "points"
    with h5py.File(path, "r+") as f:  # a file that does not declare it
        del f.attrs["targets"]
    assert read_recording(path).targets == "people"
    with h5py.File(path, "r+") as f:
        f.attrs["targets"] = "cars"
    with pytest.raises(FileFormatError, match="targets='cars' must be one of"):
        read_recording(path)


def test_large_datasets_are_chunked_and_compressed(tmp_path):
    path = write_recording(tmp_path / "r.h5", _recording())
    with h5py.File(path, "r") as f:
        pc = f["nodes/S1/point_cloud/range_m"]
        assert pc.chunks is not None and pc.compression == "gzip"
        adc = f["nodes/S1/cube/adc"]
        assert adc.chunks == (1, *SMALL_RADAR.cube_shape) and adc.compression == "gzip"
        assert f.attrs["format"] == FORMAT_NAME


def test_empty_levels_round_trip(tmp_path):
    rec = Recording(frame_period_s=0.1, nodes={
        "S1": NodeData(name="S1", centroids=Detections.empty(), tracks=Tracks.empty())})
    back = read_recording(write_recording(tmp_path / "e.h5", rec))
    assert len(back.nodes["S1"].centroids) == 0 and len(back.nodes["S1"].tracks) == 0
    assert back.truth is None


def test_write_refuses_existing_file_without_overwrite(tmp_path):
    path = write_recording(tmp_path / "r.h5", _recording())
    with pytest.raises(FileFormatError, match="exists; pass overwrite=True"):
        write_recording(path, _recording())
    write_recording(path, _recording(seed=1), overwrite=True)
    assert read_recording(path).metadata["seed"] == 7


def test_failed_write_leaves_old_file_and_no_temporary(tmp_path):
    path = write_recording(tmp_path / "r.h5", _recording())
    before = path.read_bytes()
    bad = Recording(frame_period_s=0.1, nodes={"S1": NodeData(name="S1")},
                    metadata={"obj": {"a": 1}})
    with pytest.raises(FileFormatError, match="metadata"):
        write_recording(path, bad, overwrite=True)
    assert path.read_bytes() == before
    assert sorted(os.listdir(tmp_path)) == ["r.h5"]


def test_update_keeps_extension_groups_and_unloaded_cubes(tmp_path):
    rec = _recording()
    path = write_recording(tmp_path / "r.h5", rec)
    with h5py.File(path, "a") as f:
        cal = f.create_group("calibration")
        cal.attrs["reference"] = "S1"
        cal.create_dataset("pose_covariance", data=np.eye(3))
        f.create_group("fused").create_dataset("x_m", data=np.arange(5.0))
        f["nodes/S1"].create_dataset("extra_notes", data=np.arange(3))
        f.attrs["tool"] = "someone else"
    light = read_recording(path, load_cubes=False)
    assert light.nodes["S1"].cube is None and light.nodes["S1"].radar == SMALL_RADAR
    new_tracks = Tracks(frame=[1, 2], track_id=[5, 5], state=np.ones((2, 4)),
                        covariance=np.tile(np.eye(4), (2, 1, 1)))
    import dataclasses
    updated = light.with_node(dataclasses.replace(light.nodes["S1"], tracks=new_tracks,
                                                  pose=[0.0, 0.0, 0.0]))
    update_recording(path, updated)
    back = read_recording(path)
    assert_array_equal(back.nodes["S1"].tracks.track_id, [5, 5])
    assert_array_equal(back.nodes["S1"].cube, rec.nodes["S1"].cube)
    assert back.node_names == rec.node_names
    with h5py.File(path, "r") as f:
        assert f["calibration"].attrs["reference"] == "S1"
        assert_array_equal(f["calibration/pose_covariance"][()], np.eye(3))
        assert_array_equal(f["fused/x_m"][()], np.arange(5.0))
        assert_array_equal(f["nodes/S1/extra_notes"][()], np.arange(3))
        assert f.attrs["tool"] == "someone else"
    # keep_cubes=False drops the cube the recording no longer holds.
    update_recording(path, updated, keep_cubes=False)
    with h5py.File(path, "r") as f:
        assert "cube" not in f["nodes/S1"] and "radar" in f["nodes/S1"]
    assert read_recording(path).nodes["S1"].radar == SMALL_RADAR


def test_update_needs_an_existing_valid_file(tmp_path):
    with pytest.raises(FileFormatError, match="does not exist; use write_recording"):
        update_recording(tmp_path / "none.h5", _recording())


def test_iter_cubes_chunks(tmp_path):
    rec = _recording(cube_frames=5)
    path = write_recording(tmp_path / "r.h5", rec)
    chunks = list(iter_cubes(path, "S1", chunk_frames=2))
    assert [len(fr) for fr, _ in chunks] == [2, 2, 1]
    assert_array_equal(np.concatenate([c for _, c in chunks]), rec.nodes["S1"].cube)
    assert_array_equal(np.concatenate([fr for fr, _ in chunks]), np.arange(10, 15))
    radar, frames, n = read_cube_frames(path, "S1")
    assert radar == SMALL_RADAR and n == 5
    with pytest.raises(FileFormatError, match="/nodes/S9 is missing"):
        list(iter_cubes(path, "S9"))
    with pytest.raises(FileFormatError, match="/nodes/Z9/cube is missing"):
        list(iter_cubes(path, "Z9"))
    with pytest.raises(FileFormatError, match="chunk_frames=0"):
        list(iter_cubes(path, "S1", chunk_frames=0))


def test_plain_h5py_writer_is_readable(tmp_path):
    """The docs/FORMAT.md example: a minimal file written with h5py alone."""
    path = tmp_path / "plain.h5"
    with h5py.File(path, "w") as f:
        f.attrs["format"] = "mmsnap_graph.recording"
        f.attrs["format_version"] = "1.0"
        f.attrs["frame_period_s"] = 0.15
        f.attrs["node_order"] = ["S1", "S2"]
        for name in ("S1", "S2"):
            c = f.create_group(f"nodes/{name}/centroids")
            c["frame"] = np.arange(3)
            c["range_m"] = [3.0, 3.1, 3.2]
            c["omega_rad"] = [0.1, 0.2, 0.3]
            c["doppler_mps"] = [1.0, 1.0, 1.0]
        f["nodes/S2"].attrs["pose"] = [0.0, 7.0, np.pi]
    rec = read_recording(path)
    assert rec.node_names == ["S1", "S2"]
    assert_array_equal(rec.nodes["S2"].pose, [0.0, 7.0, np.pi])
    assert rec.nodes["S1"].pose is None
    assert_array_equal(rec.nodes["S1"].centroids.range_m, [3.0, 3.1, 3.2])


# ---- reader errors ---------------------------------------------------------
def _broken(tmp_path, edit) -> Path:
    path = write_recording(tmp_path / "b.h5", _recording(n_points=50))
    with h5py.File(path, "a") as f:
        edit(f)
    return path


@pytest.mark.parametrize("edit, match", [
    (lambda f: f.attrs.__delitem__("frame_period_s"), "/ is missing attribute 'frame_period_s'"),
    (lambda f: f.attrs.__setitem__("frame_period_s", "fast"), "'frame_period_s' must be a finite"),
    (lambda f: f.attrs.__setitem__("format", "other"), "attribute 'format' must be"),
    (lambda f: f.attrs.__setitem__("format_version", "2.0"), "reads version 1.x"),
    (lambda f: f.attrs.__setitem__("node_order", ["S1", "Z9"]), "does not list the groups"),
    (lambda f: f.__delitem__("nodes"), "/nodes is missing"),
    (lambda f: (f.__delitem__("nodes/Z9"), f["nodes"].create_dataset("Z9", data=1)),
     "/nodes/Z9 must be a group"),
    (lambda f: f.__delitem__("nodes/S1/centroids/range_m"),
     "dataset /nodes/S1/centroids/range_m is missing"),
    (lambda f: f.__delitem__("nodes/S1/tracks/covariance"),
     "dataset /nodes/S1/tracks/covariance is missing"),
    (lambda f: f.__delitem__("truth/vx_mps"), "dataset /truth/vx_mps is missing"),
    (lambda f: f.__delitem__("nodes/S1/cube/adc"), "dataset /nodes/S1/cube/adc is missing"),
    (lambda f: f["nodes/S1/cube"].attrs.__delitem__("n_loops"),
     "/nodes/S1/cube is missing attribute 'n_loops'"),
    (lambda f: f["nodes/S1/cube"].attrs.__setitem__("n_loops", 5),
     "/nodes/S1/cube/adc has shape"),
    (lambda f: f["nodes/S1/cube"].attrs.__setitem__("chirp_period_s", 1.0),
     "inconsistent radar configuration"),
    (lambda f: f["nodes/A0"].attrs.__setitem__("pose", [1.0, 2.0]),
     "/nodes/A0 attribute 'pose' must be 3 finite numbers"),
])
def test_reader_names_missing_or_malformed_fields(tmp_path, edit, match):
    path = _broken(tmp_path, edit)
    with pytest.raises(FileFormatError, match=match):
        read_recording(path)


def _replace(f, name, data):
    del f[name]
    f[name] = data


@pytest.mark.parametrize("name, data, match", [
    ("nodes/S1/centroids/frame", np.arange(30) + 0.5, "centroids/frame must hold int values"),
    ("nodes/S1/centroids/omega_rad", np.array(["a"] * 30, dtype="S1"),
     "centroids/omega_rad must hold float values"),
    ("nodes/S1/point_cloud/snr_db", np.zeros(49), "snr_db has 49 rows but"),
    ("nodes/S1/centroids/doppler_mps", np.zeros((30, 2)), "doppler_mps must be 1-D"),
    ("nodes/S1/tracks/covariance", np.zeros((40, 4, 3)), "covariance must have shape"),
    ("nodes/S1/tracks/track_id", np.zeros(41, int), "track_id has 41 rows"),
    ("nodes/S1/cube/adc", np.zeros((3, 16, 4, 12)), "adc must hold complex values"),
    ("nodes/S1/cube/frame", np.arange(4), "cube/frame has 4 rows"),
    ("truth/x_m", np.full(40, np.nan), "truth/x_m must be finite"),
    ("nodes/S1/centroids/range_m", -np.ones(30), "range_m must be >= 0"),
])
def test_reader_rejects_wrong_dtypes_and_lengths(tmp_path, name, data, match):
    path = _broken(tmp_path, lambda f: _replace(f, name, data))
    with pytest.raises(FileFormatError, match=match):
        read_recording(path)


def test_reader_rejects_truncated_and_foreign_files(tmp_path):
    path = write_recording(tmp_path / "r.h5", _recording())
    data = path.read_bytes()
    trunc = tmp_path / "t.h5"
    trunc.write_bytes(data[: len(data) // 2])
    with pytest.raises(FileFormatError, match="truncated|cannot be read"):
        read_recording(trunc)
    text = tmp_path / "x.h5"
    text.write_text("not hdf5")
    with pytest.raises(FileFormatError, match="not a readable HDF5 file"):
        read_recording(text)
    with pytest.raises(FileFormatError, match="does not exist"):
        read_recording(tmp_path / "missing.h5")
    with h5py.File(tmp_path / "other.h5", "w") as f:
        f["x"] = 1
    with pytest.raises(FileFormatError, match="missing attribute 'format'"):
        read_recording(tmp_path / "other.h5")


def test_int16_cube_storage_round_trips_counts(tmp_path):
    rng = np.random.default_rng(4)
    counts = (rng.integers(-300, 300, (2, *SMALL_RADAR.cube_shape))
              + 1j * rng.integers(-300, 300, (2, *SMALL_RADAR.cube_shape))).astype(np.complex64)
    rec = Recording(frame_period_s=0.15, nodes={
        "S1": NodeData(name="S1", radar=SMALL_RADAR, cube=counts)})
    path = write_recording(tmp_path / "i.h5", rec, cube_storage="int16")
    with h5py.File(path, "r") as f:
        assert f["nodes/S1/cube/adc"].dtype == np.int16
        assert f["nodes/S1/cube/adc"].shape == (2, *SMALL_RADAR.cube_shape, 2)
    assert_array_equal(read_recording(path).nodes["S1"].cube, counts)
    chunks = list(iter_cubes(path, "S1", chunk_frames=1))
    assert_array_equal(np.concatenate([c for _, c in chunks]), counts)
    frac = Recording(frame_period_s=0.15, nodes={
        "S1": NodeData(name="S1", radar=SMALL_RADAR, cube=counts + 0.5)})
    with pytest.raises(FileFormatError, match="not whole int16 ADC counts"):
        write_recording(tmp_path / "f.h5", frac, cube_storage="int16")
    with pytest.raises(FileFormatError, match="cube_storage='int8'"):
        write_recording(tmp_path / "g.h5", rec, cube_storage="int8")
    # A 5-D adc that is not int16 I/Q pairs.
    with h5py.File(path, "a") as f:
        del f["nodes/S1/cube/adc"]
        f["nodes/S1/cube/adc"] = np.zeros((2, *SMALL_RADAR.cube_shape, 2), dtype=np.int32)
    with pytest.raises(FileFormatError, match="stored as ADC counts must be int16"):
        read_recording(path)


def test_ti_radar_fields_round_trip(tmp_path):
    radar = dataclasses.replace(TABLE_I, adc_start_s=6e-6, rx_elevation_half_wl=(0.0, 0.0, 0.0, 0.0),
                                tx_channels=(0, 2, 1), wavelength_reference="band_centre")
    rec = simulate_recording("B", "straight", CLEAN, levels=("centroids",), n_frames=5, seed=1)
    nodes = {n: dataclasses.replace(d, radar=radar) for n, d in rec.nodes.items()}
    rec = dataclasses.replace(rec, nodes=nodes)
    path = write_recording(tmp_path / "ti.h5", rec)
    back = read_recording(path).nodes["S1"].radar
    assert back == radar
    assert back.wavelength_m == radar.wavelength_m != TABLE_I.wavelength_m
    np.testing.assert_array_equal(back.tx_channels, (0, 2, 1))


# Fuzzing: ``read_recording`` on a damaged file raises only the project's errors
# (a FileFormatError naming what is wrong), never an h5py or numpy exception.


FUZZ = settings(max_examples=80, deadline=None, derandomize=True, database=None,
                report_multiple_bugs=False, suppress_health_check=[HealthCheck.too_slow])


_names = itertools.count()


class Source(tuple):
    """(bytes of the file, folder for damaged copies), with a short repr."""

    def __repr__(self) -> str:
        return f"<recording of {len(self[0])} bytes>"


@pytest.fixture(scope="module")
def recording_bytes(tmp_path_factory) -> Source:
    """A small valid recording (2 nodes, 40 frames, centroids and point
    clouds), and a folder for the damaged copies."""
    d = tmp_path_factory.mktemp("fuzz_io")
    path = d / "good.h5"
    assert main(["simulate", "--model", "clean", "-c", "B", "-t", "random", "-n", "40", "--seed", "3",
                 "-o", str(path), "--no-progress"]) == 0
    read_recording(path)  # the undamaged file reads
    return Source((path.read_bytes(), d))


def read_damaged(data: bytes, folder: Path) -> None:
    """Write ``data`` to a fresh file and read it; a project error is fine."""
    path = folder / f"damaged_{next(_names)}.h5"
    path.write_bytes(data)
    try:
        read_recording(path)
    except MmsnapError:
        pass
    finally:
        path.unlink()


@FUZZ
@given(st.floats(0.0, 0.999))
def test_a_truncated_file_raises_only_typed_errors(recording_bytes, keep_fraction):
    data, folder = recording_bytes
    read_damaged(data[:int(len(data) * keep_fraction)], folder)


@FUZZ
@given(st.integers(0, 2**32 - 1))
def test_a_file_whose_body_is_garbage_raises_only_typed_errors(recording_bytes, seed):
    data, folder = recording_bytes
    rng = np.random.default_rng(seed)
    start = int(rng.integers(0, 512))
    garbage = rng.integers(0, 256, len(data) - start, dtype=np.uint8).tobytes()
    read_damaged(data[:start] + garbage, folder)


@FUZZ
@given(st.lists(st.tuples(st.integers(0, 2**31), st.integers(0, 7)), min_size=1, max_size=16))
def test_a_bit_flipped_file_raises_only_typed_errors(recording_bytes, flips):
    data, folder = recording_bytes
    damaged = bytearray(data)
    for position, bit in flips:
        damaged[position % len(damaged)] ^= 1 << bit
    read_damaged(bytes(damaged), folder)


def test_uint64_frames_beyond_int64_are_a_format_error(recording_b_file, tmp_path):
    path = tmp_path / "u64.h5"
    path.write_bytes(recording_b_file.read_bytes())
    with h5py.File(path, "r+") as f:
        g = f["nodes/S1/centroids"]
        n = g["frame"].shape[0]
        del g["frame"]
        g.create_dataset("frame", data=np.arange(n, dtype=np.uint64) + np.uint64(2**63))
    with pytest.raises(FileFormatError, match="frame"):
        read_recording(path)
