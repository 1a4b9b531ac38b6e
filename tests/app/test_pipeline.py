"""The chain on in-memory recordings and on HDF5 files (``mmsnap process``)."""

import dataclasses
from pathlib import Path
import subprocess
import sys
import time

import numpy as np
import pytest
import h5py

from factors.models import global_to_local
from _cli import mmsnap, simulated
from mmsnap_graph.app.cli import main
from mmsnap_graph.app.pipeline import (
    cluster_node,
    process_node,
    process_recording,
    track_node,
    track_recording,
)
from mmsnap_graph.app.pipeline import SPARSE_POINTS_PER_FRAME, sparse_cluster_config
from mmsnap_graph.data.radar_config import TABLE_I
from mmsnap_graph.data.recording import Detections, NodeData, Recording
from mmsnap_graph.errors import ValidationError
from mmsnap_graph.radar.chain import ChainConfig
from mmsnap_graph.sim import network_poses, CLEAN, simulate_recording
from mmsnap_graph.sim.body import body_scatterers
from mmsnap_graph.sim.cube import scatterer_amplitude, synthesize_cubes
from mmsnap_graph.sim.real.sparse import sparse_clouds

POSES = network_poses("C")
N_FRAMES = 16


def _truth_states():
    t = np.arange(N_FRAMES) * TABLE_I.frame_period_s
    # Walking along y between the two radars, slightly off the axis.
    return np.stack([0.6 + 0 * t, 2.0 + 1.1 * t, 0 * t, np.full(N_FRAMES, 1.1)], axis=1)


def _recording(seed=0, with_cubes=("S1", "S2")):
    rng = np.random.default_rng(seed)
    states = _truth_states()
    body = body_scatterers(states, TABLE_I.frame_period_s, rng=rng)
    nodes = {}
    for name, pose in POSES.items():
        c, s = np.cos(pose[2]), np.sin(pose[2])
        rot = np.array([[c, s], [-s, c]])
        pos = global_to_local(body.positions_m, pose)
        vel = body.velocities_mps @ rot.T
        r = np.hypot(pos[..., 0], pos[..., 1])
        amp = scatterer_amplitude(TABLE_I, body.rcs_m2[None, :], r) \
            * np.exp(2j * np.pi * rng.random(r.shape))
        if name in with_cubes:
            cubes = synthesize_cubes(TABLE_I, pos, vel, amp, rng=rng, noise_std=1.0)
            nodes[name] = NodeData(name=name, radar=TABLE_I, cube=cubes)
        else:
            nodes[name] = NodeData(name=name, radar=TABLE_I)
    return Recording(frame_period_s=TABLE_I.frame_period_s, nodes=nodes), states


def _local_truth(states, pose):
    c, s = np.cos(pose[2]), np.sin(pose[2])
    rot = np.array([[c, s], [-s, c]])
    return np.concatenate([global_to_local(states[:, :2], pose), states[:, 2:] @ rot.T], axis=1)


@pytest.mark.slow
def test_process_recording_fills_every_level():
    rec, states = _recording()
    out, reports = process_recording(rec)
    for name, pose in POSES.items():
        node = out.nodes[name]
        rep = reports[name]
        assert rep.level == "cube" and rep.success and rep.n_frames == N_FRAMES
        assert len(node.point_cloud) > N_FRAMES
        # One centroid per frame, close to the torso in the local frame.
        assert np.unique(node.centroids.frame).size >= N_FRAMES - 1
        truth = _local_truth(states, pose)
        r_true = np.hypot(truth[node.centroids.frame, 0], truth[node.centroids.frame, 1])
        assert np.median(np.abs(node.centroids.range_m - r_true)) < 0.1
        # One confirmed track, in the local frame, near the truth.
        assert node.tracks.track_ids.size == 1
        err = node.tracks.state[:, :2] - truth[node.tracks.frame, :2]
        assert np.sqrt(np.mean(np.sum(err**2, axis=1))) < 0.5
        np.testing.assert_allclose(node.tracks.covariance,
                                   np.swapaxes(node.tracks.covariance, 1, 2))
    # The input is unchanged (values are frozen; new nodes were made).
    assert rec.nodes["S1"].point_cloud is None


def test_centroids_only_tracking_and_missing_levels():
    rec, states = _recording(with_cubes=("S1",))
    out, reports = process_recording(rec)
    assert reports["S2"].level == "none" and not reports["S2"].success
    # Give S2 S1's centroids (as a recording without cubes would have) and track.
    s2 = NodeData(name="S2", centroids=out.nodes["S1"].centroids)
    rec2 = out.with_node(s2)
    tracked, rep2 = track_recording(rec2)
    assert rep2["S2"].level == "centroids"
    np.testing.assert_allclose(tracked.nodes["S2"].tracks.state, out.nodes["S1"].tracks.state)
    node, rep = track_node(s2, rec.frame_period_s)
    assert rep.n_tracks == 1
    with pytest.raises(ValidationError, match="has no centroids"):
        track_node(NodeData(name="S3"), 0.15)
    with pytest.raises(ValidationError, match="has no cube"):
        process_node(NodeData(name="S3"), 0.15)


def test_point_cloud_level_is_clustered_and_tracked():
    """A node stored at the point-cloud level (no cube) gets the same torso
    centroids and tracks the full chain derives from that point cloud."""
    rec, _ = _recording(with_cubes=("S1",))
    full, _ = process_recording(rec)
    s1 = full.nodes["S1"]
    pc_only = full.with_node(NodeData(name="S1", radar=s1.radar, point_cloud=s1.point_cloud))
    out, reports = process_recording(pc_only)
    assert reports["S1"].level == "point_cloud" and reports["S1"].success
    np.testing.assert_allclose(out.nodes["S1"].centroids.measurements, s1.centroids.measurements)
    np.testing.assert_allclose(out.nodes["S1"].tracks.state, s1.tracks.state)
    node, rep = cluster_node(pc_only.nodes["S1"], rec.frame_period_s)
    assert rep.n_points == len(s1.point_cloud) and rep.n_tracks == 1
    with pytest.raises(ValidationError, match="has no point cloud"):
        cluster_node(NodeData(name="S3"), 0.15)


@pytest.mark.slow
def test_cli_process_updates_a_file(tmp_path, capsys):
    io = pytest.importorskip("mmsnap_graph.io")
    rec, states = _recording(seed=1)
    path = tmp_path / "rec.h5"
    io.write_recording(path, rec, compression=None)
    out_path = tmp_path / "out.h5"
    assert main(["process", str(path), "--output", str(out_path), "--no-progress"]) == 0
    text = capsys.readouterr().out
    assert "S1: cube:" in text and "wrote" in text
    got = io.read_recording(out_path, load_cubes=False)
    ref, _ = process_recording(rec)
    for name in POSES:
        a, b = got.nodes[name], ref.nodes[name]
        np.testing.assert_allclose(a.centroids.measurements, b.centroids.measurements)
        np.testing.assert_allclose(a.tracks.state, b.tracks.state)
        assert len(a.point_cloud) == len(b.point_cloud)
    # The cubes are still in the output; the input was not touched.
    assert io.read_recording(out_path).nodes["S1"].cube.shape == (N_FRAMES, *TABLE_I.cube_shape)
    assert io.read_recording(path, load_cubes=False).nodes["S1"].centroids is None
    # In place, centroids only: tracks rebuilt from the stored centroids.
    assert main(["process", str(out_path), "--centroids-only", "--no-progress"]) == 0
    again = io.read_recording(out_path, load_cubes=False)
    np.testing.assert_allclose(again.nodes["S2"].tracks.state, ref.nodes["S2"].tracks.state)


def test_cli_process_reports_a_missing_file(tmp_path, capsys):
    pytest.importorskip("mmsnap_graph.io")
    assert main(["process", str(tmp_path / "nope.h5"), "--no-progress"]) == 1
    assert "does not exist" in capsys.readouterr().err


@pytest.mark.slow
def test_the_chain_does_not_import_gtsam():
    import subprocess
    import sys

    code = ("import sys, mmsnap_graph.app.pipeline, mmsnap_graph.sim.cube, "
            "mmsnap_graph.app.commands.process; print('gtsam' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_sparse_clouds_are_clustered_with_one_point_minimum(point_cloud_recording_3):
    sparse = sparse_clouds(point_cloud_recording_3, seed=4)
    cfg = ChainConfig()
    same, changed = sparse_cluster_config(point_cloud_recording_3.nodes["S1"].point_cloud, cfg)
    assert same is cfg and not changed                         # ~35 points per frame
    thin, changed = sparse_cluster_config(sparse.nodes["S1"].point_cloud, cfg)
    assert changed and thin.cluster.min_samples == 1
    assert thin.cluster.eps_m == cfg.cluster.eps_m             # the rest kept
    kept, changed = sparse_cluster_config(sparse.nodes["S1"].point_cloud, cfg, sparse=False)
    assert kept is cfg and not changed
    forced, changed = sparse_cluster_config(point_cloud_recording_3.nodes["S1"].point_cloud, cfg,
                                            sparse=True)
    assert changed and forced.cluster.min_samples == 1
    counts = np.bincount(sparse.nodes["S1"].point_cloud.frame)
    assert np.median(counts[counts > 0]) < SPARSE_POINTS_PER_FRAME


def test_sparse_node_gets_a_centroid_in_most_non_empty_frames(point_cloud_recording_3):
    node = sparse_clouds(point_cloud_recording_3, seed=4).nodes["S2"]
    auto, rep = cluster_node(node, point_cloud_recording_3.frame_period_s)
    off, _ = cluster_node(node, point_cloud_recording_3.frame_period_s, sparse=False)
    full = np.unique(node.point_cloud.frame).size
    assert np.unique(auto.centroids.frame).size > 0.9 * full
    assert np.unique(off.centroids.frame).size < 0.5 * full     # DBSCAN's 3-point minimum
    assert "sparse cloud" in rep.message


def test_a_static_scene_does_not_make_a_sparse_cloud_dense(point_cloud_recording_3):
    """Whether a cloud is sparse is decided on the points that are clustered:
    a wall's zero-Doppler points (six per frame here, at fixed places), which
    the static-scene filter drops, would otherwise lift the median frame above
    :data:`SPARSE_POINTS_PER_FRAME` and DBSCAN's 3-point minimum would lose the
    walkers' 2-3 points (the first half of the two-person recording: S2's
    median frame 6 points with its walls, 3 without)."""
    node = sparse_clouds(point_cloud_recording_3, seed=4).nodes["S2"]
    pc = node.point_cloud
    frames = np.unique(pc.frame)
    wall = np.linspace(-1.2, 1.2, 6)                      # omega of six fixed reflectors
    n = frames.size * wall.size
    walled = Detections(
        frame=np.concatenate([pc.frame, np.repeat(frames, wall.size)]),
        range_m=np.concatenate([pc.range_m, np.full(n, 6.5)]),
        omega_rad=np.concatenate([pc.omega_rad, np.tile(wall, frames.size)]),
        doppler_mps=np.concatenate([pc.doppler_mps, np.zeros(n)]))
    counts = np.unique(walled.frame, return_counts=True)[1]
    assert np.median(counts) >= SPARSE_POINTS_PER_FRAME
    out, rep = cluster_node(dataclasses.replace(node, point_cloud=walled),
                            point_cloud_recording_3.frame_period_s)
    assert "sparse cloud" in rep.message and "static-scene points" in rep.message
    assert np.unique(out.centroids.frame).size > 0.9 * frames.size


def test_process_node_wraps_the_ekf_doppler_at_the_chains_unambiguous_speed(monkeypatch):
    """The pipeline hands the chain's unambiguous speed to the EKF (issue 14):
    without it the EKF never wrapped its Doppler innovation."""
    from mmsnap_graph.app import pipeline
    from mmsnap_graph.radar.chain import unambiguous_speed_mps

    seen = {}

    def spy(centroids, config, **kw):
        seen["wrap"] = config.doppler_wrap_mps
        return real(centroids, config, **kw)

    real = pipeline.track_centroids
    monkeypatch.setattr(pipeline, "track_centroids", spy)
    rec = simulate_recording("B", "straight", CLEAN, levels=("cube",), n_frames=2, seed=2)
    node = rec.nodes["S1"]
    pipeline.process_node(node, rec.frame_period_s)
    assert seen["wrap"] == unambiguous_speed_mps(node.radar)


@pytest.fixture()
def recording(tmp_path) -> Path:
    return simulated(tmp_path / "rec.h5", 300)


def test_a_second_writer_waits_for_the_lock(recording):
    """A process holding the lock makes `mmsnap process` wait, not interleave."""
    holder = subprocess.Popen(
        [sys.executable, "-c",
         "import sys, time; from mmsnap_graph._atomic import recording_lock\n"
         f"with recording_lock({str(recording)!r}):\n"
         "    print('locked', flush=True); time.sleep(3)\n"],
        stdout=subprocess.PIPE, text=True)
    assert holder.stdout.readline().strip() == "locked"
    t0 = time.monotonic()
    proc = mmsnap("process", str(recording), "--centroids-only", "--no-progress")
    out, err = proc.communicate(timeout=600)
    holder.wait(timeout=60)
    assert proc.returncode == 0, err
    assert time.monotonic() - t0 > 1.5  # it waited for the holder
    with h5py.File(recording, "r") as f:
        assert "tracks" in f["nodes/S1"]


def test_a_killed_write_leaves_a_temporary_that_the_next_write_removes(recording):
    code = ("import os\nfrom mmsnap_graph._atomic import atomic_path\n"
            f"with atomic_path({str(recording)!r}) as tmp:\n"
            "    tmp.write_bytes(b'x' * 1000)\n    os._exit(9)\n")
    assert subprocess.run([sys.executable, "-c", code], timeout=120).returncode == 9
    assert len(list(recording.parent.glob(".rec.h5.*.tmp"))) == 1
    assert main(["process", str(recording), "--centroids-only", "--no-progress"]) == 0
    assert not list(recording.parent.glob(".rec.h5.*.tmp"))


@pytest.mark.parametrize("far", [2 ** 31, 2 ** 62])
def test_a_far_frame_number_does_not_size_the_sparse_check(far):
    # One flipped header bit puts a frame at 2^31: counting points per frame
    # over the frame span asked for 16 GiB (2^62: for exabytes).
    import tracemalloc
    from mmsnap_graph.app.pipeline import sparse_cluster_config
    from mmsnap_graph.data.recording import Detections
    from mmsnap_graph.radar.chain import ChainConfig
    frame = np.array([0, 0, 1, 1, 2, 2, far, far])
    cloud = Detections(frame=frame, range_m=np.full(8, 3.0), omega_rad=np.zeros(8),
                       doppler_mps=np.zeros(8))
    tracemalloc.start()
    try:
        _, sparse = sparse_cluster_config(cloud, ChainConfig())
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert sparse and peak < 10e6
