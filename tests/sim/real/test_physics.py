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


# Body images (multipath) in the point clouds: the geometry of the real
# recordings (S1 at the origin facing +y, S2 at (1.70, 1.65) m facing -x),
# the recordings' room box, one walker; no false alarms and no static points,
# so that every unlabelled moving point is an image.
ROOM = (-2.0, 1.6, 0.0, 3.6)


def _images_run(**knobs):
    from mmsnap_graph.sim import Area
    from mmsnap_graph.sim.trajectories import make_trajectory

    area = Area(x_min_m=-1.6, x_max_m=1.0, y_min_m=0.8, y_max_m=3.3)
    states = make_trajectory("random", area, n_frames=1200, frame_period_s=0.05,
                             rng=np.random.default_rng(3))[None]
    ph = RealPhysics(room=ROOM, false_alarm_fraction=0.0, static_points_per_frame=0.0, **knobs)
    opt = SimulationOptions(frame_period_s=0.05, min_range_m=0.25, physics=ph)
    return simulate_recording({"S1": (0.0, 0.0, 0.0), "S2": (1.70, 1.65, np.pi / 2)}, states,
                              opt, levels=("point_cloud",), seed=5)


def _global(pc, pose):
    from factors.models import local_to_global

    th = np.arcsin(pc.omega_rad / np.pi)
    return local_to_global(np.stack([pc.range_m * np.sin(th), pc.range_m * np.cos(th)], 1), pose)


def test_body_images_are_weaker_copies_beyond_a_side_wall_in_episodes():
    """Measured on the real recordings (tools/measure_real_recordings.py): a
    walker's image points lie 0.4-1.0 m (median) beyond a side wall, about 12
    dB weaker, at the one-bounce path length (median range residual -0.1 to
    +0.4 m; the mirror image's -0.9 to -1.3 m), in episodes of frames."""
    rec = _images_run()
    room = np.array(ROOM)
    for name in ("S1", "S2"):
        pc, pose = rec.nodes[name].point_cloud, rec.truth.node_poses[name]
        xy = _global(pc, pose)
        img = pc.target_id == -1
        assert img.sum() > 40
        depth = np.stack([room[0] - xy[:, 0], xy[:, 0] - room[1],
                          room[2] - xy[:, 1], xy[:, 1] - room[3]], 1)
        wall = np.argmax(depth[img], 1)
        assert np.all(depth[img].max(1) > -0.3)              # beyond a wall (body's extent)
        side = (0, 1) if name == "S1" else (2, 3)           # along the boresight
        assert np.all(np.isin(wall, side))
        # SNR: about 12 dB below the body's points of the same frames.
        body_snr = np.median(pc.snr_db[pc.target_id == 0])
        assert -16 < np.median(pc.snr_db[img]) - body_snr < -8
        # Path length: one bounce, (|P - S| + |M - S|) / 2, within the body's size.
        state = rec.truth.state[pc.frame[img]]
        m = state[:, :2].copy()
        ax = wall // 2
        m[np.arange(m.shape[0]), ax] = 2 * room[wall] - state[np.arange(m.shape[0]), ax]
        r_p = np.linalg.norm(state[:, :2] - pose[:2], axis=1)
        r_m = np.linalg.norm(m - pose[:2], axis=1)
        assert abs(np.median(pc.range_m[img] - (r_p + r_m) / 2)) < 0.15
        assert np.median(pc.range_m[img] - r_m) < -0.3
        # Episodes: most image frames have another within 0.5 s.
        f = np.unique(pc.frame[img])
        near = np.array([np.sum(np.abs(f - k) <= 10) >= 2 for k in f])
        assert near.mean() > 0.6, near.mean()


def test_body_images_have_the_doppler_of_their_path():
    """The one-bounce image's radial speed is the mean of the body's and its
    mirror image's (mirror velocity through the wall): the walls learned in
    fusion test exactly that."""
    rec = _images_run(image_mirror_share=0.0, quantize=False)
    room = np.array(ROOM)
    pc, pose = rec.nodes["S1"].point_cloud, rec.truth.node_poses["S1"]
    img = pc.target_id == -1
    xy = _global(pc, pose)[img]
    state = rec.truth.state[pc.frame[img]]
    wall = np.where(xy[:, 0] < room[0], 0, 1)
    m, v = state[:, :2].copy(), state[:, 2:].copy()
    k = np.arange(len(m))
    m[k, 0] = 2 * room[wall] - state[k, 0]
    v[k, 0] = -state[k, 2]
    h_p, _ = measurement_model(state, pose)
    h_m, _ = measurement_model(np.concatenate([m, v], 1), pose)
    predicted = (h_p[:, 2] + h_m[:, 2]) / 2
    # The body's micro-Doppler (limbs) is carried over: compare medians.
    assert np.median(np.abs(pc.doppler_mps[img] - predicted)) < 0.25
    assert np.median(np.abs(pc.doppler_mps[img] - h_p[:, 2])) > np.median(
        np.abs(pc.doppler_mps[img] - predicted))


def test_body_images_off_leave_the_rest_of_the_cloud_unchanged():
    on, off = _images_run(), _images_run(image_fraction=0.0)
    for name in ("S1", "S2"):
        a, b = on.nodes[name].point_cloud, off.nodes[name].point_cloud
        assert np.all(b.target_id >= 0)
        own_a, own_b = a.target_id >= 0, b.target_id >= 0
        np.testing.assert_array_equal(a.range_m[own_a], b.range_m[own_b])
        np.testing.assert_array_equal(a.doppler_mps[own_a], b.doppler_mps[own_b])
        assert len(a) > len(b)


def _fused_run(path, *flags):
    from mmsnap_graph.app.cli import main
    from mmsnap_graph.io import read_recording
    from mmsnap_graph.io.fused import read_fused

    assert main(["fuse", str(path), "--no-progress", *flags]) == 0
    rec, fused = read_recording(path, load_cubes=False), read_fused(path)
    truth, ok = rec.truth, np.asarray(fused.success, bool)
    seen = np.mean([np.any(ok & (fused.frame == f)
                           & (np.hypot(*(fused.state[:, :2] - xy).T) <= 0.5))
                    for f, xy in zip(truth.frame, truth.state[:, :2])])
    far = np.array([np.min(np.hypot(*(truth.state[truth.frame == fused.frame[k], :2]
                                      - fused.state[k, :2]).T)) > 0.5
                    for k in range(len(fused.frame))])
    return float(seen), ok, far, np.asarray(fused.status)


def test_point_cloud_images_reach_fusion_and_the_learned_walls_flag_them(tmp_path, capsys):
    """`mmsnap simulate` (real model, point clouds) -> `process` -> `fuse`,
    network B, one walker, seed 0, known poses. Measured: without the learned
    walls 96 kept rows lie more than 0.5 m from the walker (62 with them) and
    5.8% of the frames hold two or more targets (0.2% with them); the walls
    (S1's and S2's, learned from 21 and 26 frames of images) flag 40 rows,
    all images; the walker is seen within 0.5 m in 86.5% of the frames either
    way. Before the body images, no image reached fusion and no wall was
    learned (the same 0 flagged with and without the walls)."""
    from mmsnap_graph.app.cli import main

    path = tmp_path / "b.h5"
    assert main(["simulate", "-c", "B", "-t", "random", "-n", "600", "-s", "0", "--known-poses",
                 "-o", str(path), "--no-progress"]) == 0
    assert main(["process", str(path), "--no-progress"]) == 0
    # the walls alone: the placement check (on by default) flags many of these images too
    seen_off, ok_off, far_off, _ = _fused_run(path, "--no-learned-walls", "--no-placement-check")
    seen_on, ok_on, far_on, status = _fused_run(path, "--no-placement-check")
    text = capsys.readouterr().out
    assert "learned wall of" in text
    flagged = status == 11
    print(f"seen {seen_off:.3f} -> {seen_on:.3f}; far kept rows {np.sum(ok_off & far_off)} -> "
          f"{np.sum(ok_on & far_on)}; flagged {flagged.sum()}, images {np.sum(flagged & far_on)}")
    assert np.sum(ok_off & far_off) >= np.sum(ok_on & far_on) + 20     # images reach fusion
    assert flagged.sum() >= 20 and np.mean(far_on[flagged]) >= 0.95   # flagged: images
    assert abs(seen_on - seen_off) <= 0.005                            # the walker is kept
