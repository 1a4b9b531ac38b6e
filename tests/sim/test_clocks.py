"""Scenes whose nodes sample at their own clock offsets (mmsnap_graph.sim.clocks):
node time + offset = reference time, checked on ranges (no frame convention
needed) against the truth one frame later or earlier; the recording made of a
scene; the simulator's centroids (clean or real physics) with node clock
offsets (``offset_recording``)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mmsnap_graph.data.noise import MeasurementNoise
from mmsnap_graph.errors import ValidationError
from factors.models import measurement_model
from mmsnap_graph.sim import CLEAN, SimulationOptions
from mmsnap_graph.sim.clocks import (offset_recording, scene_recording, timed_scene,
                                     trajectory_function)
from mmsnap_graph.sim.scenes import COMMON_AREA_CENTERS, PAPER_CONFIGURATIONS, target_trajectory

QUIET = MeasurementNoise(range_m=1e-9, omega_rad=1e-9, doppler_mps=1e-9)
T = 0.15
POSES = PAPER_CONFIGURATIONS["C"]
CENTER = COMMON_AREA_CENTERS["C"]


def test_the_interpolated_walk_passes_through_its_grid_states():
    """``"straight"``: target_trajectory on a grid of T / 20, padded by 2 s."""
    walk = trajectory_function("straight", CENTER, duration_s=10.0, frame_period_s=T,
                               rng=np.random.default_rng(7))
    dt = T / 20
    n = int(np.ceil((10.0 + 4.0) / dt)) + 2
    grid = target_trajectory(n, CENTER, frame_period_s=dt, kind="straight",
                             rng=np.random.default_rng(7))
    t = np.arange(n) * dt - 2.0
    np.testing.assert_allclose(walk(t[::37]), grid[::37], atol=1e-12)
    with pytest.raises(ValidationError, match="times outside"):
        walk([t[-1] + 1.0])
    with pytest.raises(ValidationError, match="kind='jump'"):
        trajectory_function("jump", CENTER, duration_s=1.0, rng=np.random.default_rng(0))


@pytest.mark.parametrize("kind", ["random", "walk", "turns"])
def test_a_node_one_frame_late_measures_the_next_reference_frame(kind):
    scene = timed_scene(POSES, time_offsets_s={"S2": T}, n_frames=80, kind=kind, noise=QUIET,
                        center_m=CENTER, rng=np.random.default_rng(11))
    for name, pose in POSES.items():
        r = np.hypot(*(scene.truth[:, :2] - pose[:2]).T)
        got = scene.measurements[name][:, 0]
        if name == "S1":                                  # no offset: the reference's frames
            np.testing.assert_allclose(got, r, atol=1e-6)
        else:                                             # frame k is reference frame k + 1
            np.testing.assert_allclose(got[:-1], r[1:], atol=1e-6)
            assert np.max(np.abs(got[:-1] - r[:-1])) > 0.01
    early = timed_scene(POSES, time_offsets_s={"S2": -T}, n_frames=80, kind=kind, noise=QUIET,
                        center_m=CENTER, rng=np.random.default_rng(11))
    r2 = np.hypot(*(early.truth[:, :2] - POSES["S2"][:2]).T)
    np.testing.assert_allclose(early.measurements["S2"][1:, 0], r2[:-1], atol=1e-6)


def test_the_recording_of_a_scene_holds_its_centroids_truth_and_noise():
    noise = MeasurementNoise(range_m=0.02, omega_rad=0.1, doppler_mps=0.15)
    scene = timed_scene(POSES, time_offsets_s={"S2": 0.05}, n_frames=30, noise=noise,
                        center_m=CENTER, rng=np.random.default_rng(1))
    rec = scene_recording(scene)
    assert rec.node_names == ["S1", "S2"] and rec.frame_period_s == T
    for name in POSES:
        det = rec.nodes[name].centroids
        np.testing.assert_array_equal(det.frame, np.arange(30))
        np.testing.assert_array_equal(det.measurements, scene.measurements[name])
        np.testing.assert_array_equal(rec.truth.node_poses[name], POSES[name])
    np.testing.assert_array_equal(rec.truth.state, scene.truth)
    assert (rec.metadata["centroid_range_std_m"], rec.metadata["centroid_omega_std_rad"],
            rec.metadata["centroid_doppler_std_mps"]) == (0.02, 0.1, 0.15)


@pytest.mark.parametrize("offsets, match", [
    ({"S3": 0.1}, r"unknown nodes \['S3'\]"),
    ({"S2": float("nan")}, r"time_offsets_s\['S2'\]=nan must be finite"),
    ({"S2": 2.5}, "beyond 2 s"),
])
def test_bad_offsets_are_named(offsets, match):
    with pytest.raises(ValidationError, match=match):
        timed_scene(POSES, time_offsets_s=offsets, n_frames=20, center_m=CENTER,
                    rng=np.random.default_rng(0))


def test_each_node_is_sampled_at_its_own_times():
    """Noise-free clean centroids: S2, 0.4 frame late, measures the walker
    where it is 0.4 frame after each reference frame (the truth between two
    frames, linearly: mm at 1 m/s), not where it is at the frame (cm)."""
    quiet = dataclasses.replace(CLEAN, centroid_noise=MeasurementNoise(
        range_m=1e-9, omega_rad=1e-9, doppler_mps=1e-9))
    rec = offset_recording("B", "straight", quiet, time_offsets_s={"S2": 0.4 * T},
                           n_frames=80, seed=3)
    frame, state = rec.truth.target(0)
    assert frame.tolist() == list(range(80)) and rec.frame_period_s == T
    pose = rec.truth.node_poses["S2"]
    det = rec.nodes["S2"].centroids
    k = det.frame[det.frame < 79]
    later = 0.6 * state[k] + 0.4 * state[k + 1]
    on_frame = measurement_model(state[k], pose)[0][:, 0]
    between = measurement_model(later, pose)[0][:, 0]
    got = det.range_m[det.frame < 79]
    assert np.median(np.abs(got - between)) < 0.005
    assert np.median(np.abs(got - on_frame)) > 0.03
    ref = rec.nodes["S1"].centroids
    np.testing.assert_allclose(ref.range_m, measurement_model(state[ref.frame],
                                                              rec.truth.node_poses["S1"])[0][:, 0],
                               atol=1e-6)
    np.testing.assert_allclose(rec.metadata["time_offsets_s"], [0.0, 0.4 * T])


def test_offset_recording_argument_errors():
    with pytest.raises(ValidationError, match="milliseconds"):
        offset_recording("B", time_offsets_s={"S2": 60.0}, n_frames=10)
    with pytest.raises(ValidationError, match="unknown nodes"):
        offset_recording("B", options=CLEAN, time_offsets_s={"S9": 0.1}, n_frames=10)
    with pytest.raises(ValidationError, match="SimulationOptions"):
        offset_recording("B", options="real", time_offsets_s={}, n_frames=10)


def test_real_physics_rows_come_from_the_fine_frames():
    """The real model's extra rows (clutter, splits, ghosts) stay on the
    node's frame numbers 0..n-1."""
    rec = offset_recording("B", "straight", SimulationOptions(), time_offsets_s={"S2": -1.3 * T},
                           n_frames=40, seed=1)
    for node in rec.nodes.values():
        f = node.centroids.frame
        assert f.min() >= 0 and f.max() <= 39
        assert np.unique(f).size > 30
