"""The real physics of the simulator (docs/SIMULATOR.md, "Real physics"):
seeded checks that each knob does what it says."""

from __future__ import annotations

import numpy as np
import pytest

from factors.models import measurement_model
from mmsnap_graph.sim import CLEAN, RealPhysics, SimulationOptions, simulate_recording
from mmsnap_graph.sim.real.physics import correlated_errors, mirror_through_walls

N = 1500


@pytest.fixture(scope="module")
def real():
    return simulate_recording("C", "random", levels=("centroids", "point_cloud"), n_frames=N,
                              seed=4)


def _range_errors(rec, name):
    node = rec.nodes[name]
    c = node.centroids
    own = c.target_id == 0
    state = rec.truth.state[c.frame[own]]
    h, _ = measurement_model(state, rec.truth.node_poses[name])
    return c.frame[own], c.range_m[own] - h[:, 0]


def test_centroids_sit_on_the_near_side_of_the_body(real):
    """Each radar's centroid is biased toward it by the person's reflection depth
    (default 0.05 +- 0.015 m across people; one person here)."""
    for name in ("S1", "S2"):
        _, e = _range_errors(real, name)
        e = e[np.abs(e) < 0.5]               # split halves are 0.15-0.3 m off
        # Mean of N ~ 1,000 rows: the slow AR part (0.045 m, tau 0.7 s) leaves
        # about 0.01 m of standard error; the depth is in [0.02, 0.08] m.
        assert -0.11 < np.mean(e) < -0.01, np.mean(e)


def test_clean_model_has_no_bias_and_no_unlabelled_rows():
    rec = simulate_recording("C", "random", CLEAN, levels=("centroids",), n_frames=N, seed=4)
    _, e = _range_errors(rec, "S1")
    assert abs(np.mean(e)) < 3 * 0.05 / np.sqrt(e.size)
    assert np.all(rec.nodes["S1"].centroids.target_id == 0)


def test_slow_errors_are_ar1_with_the_stated_time_constant():
    ph = RealPhysics(fast_error_std_m=(0.0, 0.0), slow_error_std_m=0.05, slow_error_tau_s=0.7)
    e = correlated_errors(20000, 0.15, ph, np.random.default_rng(0))
    rho = np.exp(-0.15 / 0.7)
    r1 = np.mean(e[1:, 0] * e[:-1, 0]) / np.mean(e[:, 0] ** 2)
    assert abs(r1 - rho) < 0.03
    assert abs(np.std(e[:, 0]) - 0.05) < 0.005


def test_centroid_errors_are_correlated_from_frame_to_frame(real):
    frame, e = _range_errors(real, "S1")
    ok = np.abs(e) < 0.5
    frame, e = frame[ok], e[ok] - e[ok].mean()
    nxt = np.flatnonzero(np.diff(frame) == 1)
    r1 = np.mean(e[nxt] * e[nxt + 1]) / np.mean(e ** 2)
    # slow var 0.045^2 of total 0.045^2 + 0.09^2 -> 0.2, times exp(-0.15/0.7) = 0.16.
    assert 0.06 < r1 < 0.3, r1


def test_static_scene_ghosts_and_quantised_values(real):
    for name, node in real.nodes.items():
        c = node.centroids
        other = c.target_id == -1
        assert other.any()
        static = other & (c.doppler_mps == 0)
        assert static.sum() > 0.5 * N * 0.8          # about 1 static cluster per frame
        # float16: the Doppler values are exactly representable.
        assert np.array_equal(c.doppler_mps, c.doppler_mps.astype(np.float16).astype(float))
        pc = node.point_cloud
        zero = np.mean(pc.doppler_mps == 0)
        assert 0.2 < zero < 0.7, zero            # real: 0.18-0.69 per radar


def test_mirror_images_are_outside_the_room():
    room = np.array([-2.0, 2.0, -1.0, 8.0])
    xy = np.array([[0.5, 3.0]])
    ims, vel = mirror_through_walls(xy, np.array([[1.0, 0.0]]), room)
    np.testing.assert_allclose(ims[:, 0], [[-4.5, 3.0], [3.5, 3.0], [0.5, -5.0], [0.5, 13.0]])
    np.testing.assert_allclose(vel[0, 0], [-1.0, 0.0])


def test_point_clouds_are_sparse_and_self_occluded(real):
    """A few points per person and frame (real: 2.0-2.7 moving points when
    seen); their mean sits in front of the body centre as the radar sees it."""
    for name in ("S1", "S2"):
        pc = real.nodes[name].point_cloud
        own = pc.target_id == 0
        counts = np.bincount(pc.frame[own], minlength=N)
        seen = counts > 0
        assert 2.0 < counts[seen].mean() < 3.5
        assert 0.6 < seen.mean() < 0.95
        h, _ = measurement_model(real.truth.state[pc.frame[own]], real.truth.node_poses[name])
        assert np.median(pc.range_m[own] - h[:, 0]) < -0.02


def test_people_differ_in_size_and_depth():
    opt = SimulationOptions(n_targets=3)
    rec = simulate_recording("B", "random", opt, levels=("centroids",), n_frames=400, seed=8)
    means = []
    for t in range(3):
        c = rec.nodes["S1"].centroids
        own = c.target_id == t
        h, _ = measurement_model(rec.truth.state[t * 400 + c.frame[own]],
                                 rec.truth.node_poses["S1"])
        e = c.range_m[own] - h[:, 0]
        means.append(np.mean(e[np.abs(e) < 0.5]))
    assert max(means) - min(means) > 0.005


def test_truth_metadata_holds_each_persons_reflection_depth():
    rec = simulate_recording("B", "random", SimulationOptions(n_targets=2), levels=("centroids",),
                             n_frames=10, seed=1)
    d = np.asarray(rec.metadata["reflection_depth_m"])
    assert d.shape == (2,) and np.all((0 <= d) & (d <= 0.1)) and d[0] != d[1]
    clean = simulate_recording("B", "random", CLEAN, levels=("centroids",), n_frames=10, seed=1)
    assert "reflection_depth_m" not in clean.metadata


def test_fast_errors_have_the_measured_coefficient_at_20_fps():
    """Real recordings: lag-1 about 0.3 per 50 ms frame (tau 0.04 s)."""
    ph = RealPhysics(slow_error_std_m=0.0, fast_error_std_m=(0.09, 0.11))
    e = correlated_errors(20000, 0.05, ph, np.random.default_rng(1))
    r1 = np.mean(e[1:, 0] * e[:-1, 0]) / np.mean(e[:, 0] ** 2)
    assert abs(r1 - np.exp(-0.05 / 0.04)) < 0.03
    assert abs(np.std(e[:, 1]) - 0.11) < 0.005
