"""Walls learned from multipath images (mmsnap_graph.fusion.recording.walls)
and their check in screen_room."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from mmsnap_graph.data.results import Status
from mmsnap_graph.errors import ValidationError
from mmsnap_graph.fusion.recording.room import RoomBounds, screen_room
from mmsnap_graph.fusion.recording.walls import (WALL_ANGLE_TOL_RAD, WALL_MARGIN_M,
                                                  WALL_MAX_CROSSING, WALL_MIN_FRAMES,
                                                  WALL_OFFSET_TOL_M, beyond_learned_walls,
                                                  learn_walls)

from _fused_rows import fused_rows
from _fusion import config

WALL_Y = 3.6            # the far wall, seen by S1 at the origin looking along +y
N_FRAMES = 40
FRAME_S = 0.05


def walker(n=N_FRAMES):
    """A walker across the room (seen by both nodes), one row a frame:
    frames, positions, velocities."""
    t = np.arange(n)
    xy = np.c_[-1.5 + 2.5 * t / n, 1.5 + 0.8 * np.sin(t / 7.0)]
    return t, xy, np.gradient(xy, FRAME_S, axis=0)


def mirror(xy, v):
    """The mirror image through the wall and its velocity."""
    return np.c_[xy[:, 0], 2 * WALL_Y - xy[:, 1]], np.c_[v[:, 0], -v[:, 1]]


def one_bounce(xy, v):
    """S1's one-bounce image: half the path via the wall, along the mirror's
    bearing; its radial speed, half of the two paths' rates."""
    m, vm = mirror(xy, v)
    r_m, r_p = np.hypot(*m.T), np.hypot(*xy.T)
    u_m, u_p = m / r_m[:, None], xy / r_p[:, None]
    rate = (np.sum(u_m * vm, axis=1) + np.sum(u_p * v, axis=1)) / 2
    return m * ((r_p + r_m) / 2 / r_m)[:, None], u_m * rate[:, None]


def scene(image=mirror, every=1, extra=(), image_nodes=1):
    """The walker (2 nodes) and S1's image of him (``image_nodes`` nodes) in
    every ``every``-th frame, plus ``extra`` rows ``(frame, x, y, vx, vy,
    nodes)``."""
    frame, xy, v = walker()
    img = np.arange(0, N_FRAMES, every)
    g, vg = image(xy[img], v[img])
    rows = [(f, *p, *u, 2) for f, p, u in zip(frame, xy, v)]
    rows += [(f, *p, *u, image_nodes) for f, p, u in zip(img, g, vg)] + list(extra)
    rows.sort(key=lambda r: r[0])
    r = np.array(rows, dtype=float)
    return fused_rows(r[:, 0].astype(int), r[:, 1:3], velocity=r[:, 3:5],
                      nodes=r[:, 5].astype(int))


def walls_of(rows):
    return learn_walls(rows.frame, rows.state, rows.covariance, rows.success,
                       np.asarray(rows.observed), rows.node_poses, body_m=0.5)


@pytest.mark.parametrize("image", [mirror, one_bounce])
def test_images_of_a_walker_teach_the_wall(image):
    walls = walls_of(scene(image))
    assert len(walls) == 1
    w = walls[0]
    assert w.node == 0 and w.frames == N_FRAMES
    np.testing.assert_allclose(w.normal, [0.0, 1.0], atol=0.02)
    assert abs(w.offset_m - WALL_Y) < 0.05


def test_mirror_images_are_flagged_and_the_walker_kept():
    rows = scene(mirror)
    out, report = screen_room(rows, body_m=None)
    image = np.asarray(rows.observed).sum(axis=1) == 1
    np.testing.assert_array_equal(out.success, ~image)
    assert np.all(out.status[image] == Status.OUTSIDE_BOUNDS)
    assert out.message[np.flatnonzero(image)[0]].startswith(
        "beyond a wall learned from multipath images (S1: +0.00 x +1.00 y = 3.60 m")
    assert report.outside == report.beyond_wall == image.sum()
    assert report.walls == ("S1: +0.00 x +1.00 y = 3.60 m (40 frames)",)
    # The switch, and a room box, which replaces the learned walls.
    assert screen_room(rows, walls=False, body_m=None)[1].beyond_wall == 0
    box = RoomBounds(x_min=-2.0, x_max=1.6, y_min=0.0, y_max=5.0)
    assert screen_room(rows, bounds=box, body_m=None)[1].beyond_wall == 0


def test_a_mirror_image_both_radars_see_teaches_the_wall_and_is_flagged():
    """Radars on the same side of a wall see a person's mirror image through
    it as one consistent target (the image is a point for every radar):
    fused from both nodes, like the person. It still teaches the wall, and
    is flagged beyond it. (A random layout of two radars 2.2 m apart, both
    looking one way, two walkers at 20 fps: the images fused from both
    radars taught no wall, fused NEES 9.83, position RMSE 0.356 m.)"""
    rows = scene(mirror, image_nodes=2)
    walls = walls_of(rows)
    assert walls and all(abs(w.offset_m - WALL_Y) < 0.05 for w in walls)
    np.testing.assert_allclose([w.normal for w in walls], [[0.0, 1.0]] * len(walls), atol=0.02)
    out, report = screen_room(rows, body_m=None)
    image = rows.state[:, 1] > WALL_Y
    np.testing.assert_array_equal(out.success, ~image)
    assert report.beyond_wall == image.sum() == N_FRAMES


def test_a_second_person_both_radars_see_in_the_room_is_kept():
    """A second walker fused from both nodes, walking on his own in front of
    the wall (his Doppler not the walker's mirrored), teaches no wall and is
    kept."""
    t = np.arange(N_FRAMES)
    xy = np.c_[1.2 - 0.05 * t, 2.8 + 0.3 * np.cos(t / 3.0)]
    v = np.gradient(xy, FRAME_S, axis=0)
    other = [(f, *p, *u, 2) for f, p, u in zip(t, xy, v)]
    rows = scene(mirror, every=2, extra=other, image_nodes=2)
    out, _ = screen_room(rows, body_m=None)
    person = rows.state[:, 1] < WALL_Y
    assert person.sum() == 2 * N_FRAMES and out.success[person].all()


def test_learn_walls_checks_its_arrays():
    rows = scene(mirror)
    seen = np.asarray(rows.observed)
    with pytest.raises(ValidationError, match=r"seen has shape \(80, 3\)"):
        learn_walls(rows.frame, rows.state, rows.covariance, rows.success,
                    np.c_[seen, seen[:, :1]], rows.node_poses, body_m=0.5)
    with pytest.raises(ValidationError, match="body_m=0.0"):
        learn_walls(rows.frame, rows.state, rows.covariance, rows.success, seen,
                    rows.node_poses, body_m=0.0)


def test_without_images_no_wall_is_learned():
    frame, xy, v = walker()
    rows = fused_rows(frame, xy, velocity=v)
    assert walls_of(rows) == []
    out, report = screen_room(rows, body_m=None)
    assert out.success.all() and report.walls == () and report.beyond_wall == 0


def test_too_few_frames_teach_no_wall():
    every = int(np.ceil(N_FRAMES / (WALL_MIN_FRAMES - 1)))
    assert walls_of(scene(mirror, every=every)) == []
    assert len(walls_of(scene(mirror, every=N_FRAMES // WALL_MIN_FRAMES))) == 1


def test_a_person_standing_still_teaches_no_wall():
    # Static clutter behind someone standing: the same radial speed (0) as
    # his image would have, in every frame.
    rows = [(f, 0.3, 2.0, 0.0, 0.0, 2) for f in range(N_FRAMES)]
    rows += [(f, 0.3, 5.2, 0.0, 0.0, 1) for f in range(N_FRAMES)]
    r = np.array(sorted(rows, key=lambda x: x[0]), dtype=float)
    still = fused_rows(r[:, 0].astype(int), r[:, 1:3], velocity=r[:, 3:5],
                       nodes=r[:, 5].astype(int))
    assert walls_of(still) == []


def test_a_person_both_nodes_see_behind_the_line_vetoes_the_wall():
    behind = [(f, 0.5, WALL_Y + 0.8, 0.0, 0.0, 2) for f in range(N_FRAMES, N_FRAMES + 3)]
    rows = scene(mirror, extra=behind)
    assert walls_of(rows) == []
    assert screen_room(rows, body_m=None)[0].success.all()


def test_a_second_person_seen_by_one_node_in_the_room_is_kept():
    # He walks on his own (not the walker's image) in front of the wall.
    t = np.arange(N_FRAMES)
    xy = np.c_[1.2 - 0.05 * t, 2.8 + 0.3 * np.cos(t / 3.0)]
    v = np.gradient(xy, FRAME_S, axis=0)
    other = [(f, *p, *u, 1) for f, p, u in zip(t, xy, v)]
    rows = scene(mirror, every=2, extra=other)
    out, _ = screen_room(rows, body_m=None)
    person = (np.asarray(rows.observed).sum(axis=1) == 1) & (rows.state[:, 1] < WALL_Y)
    assert person.sum() == N_FRAMES and out.success[person].all()


def test_a_wall_reaches_only_along_its_images():
    rows = scene(mirror)
    walls = walls_of(rows)
    lo, hi = walls[0].along_m
    assert -1.6 < lo < hi < 1.0
    seen = np.array([[True, False]] * 3)
    # Beyond the wall: where the line of sight from S1 crosses it near the
    # images, far along it, and just beyond it (within the margin).
    xy = np.array([[0.0, 4.5], [6.0, 4.5], [0.0, WALL_Y + WALL_MARGIN_M / 2]])
    flag, which = beyond_learned_walls(np.c_[xy, np.zeros((3, 2))], np.ones(3, bool), seen,
                                       rows.node_poses, walls)
    np.testing.assert_array_equal(flag, [True, False, False])
    np.testing.assert_array_equal(which, [0, -1, -1])


def test_a_row_seen_by_a_node_on_the_other_side_is_kept():
    walls = walls_of(scene(mirror))
    # Beyond S1's wall, but also seen by S2, which has no wall there.
    flag, _ = beyond_learned_walls(np.array([[0.0, 4.5, 0.0, 0.0]]), np.array([True]),
                                   np.array([[True, True]]), scene().node_poses, walls)
    assert not flag[0]


def facing_scene(s1_frames, s2_frames):
    """Two radars facing each other 7 m apart (network C), a walker both
    see, and the mirror image of him through the side wall x = -2.5 m seen
    by S1 alone in ``s1_frames`` and by S2 alone in ``s2_frames``:
    (frame, state, covariance, ok, seen, poses)."""
    t = np.arange(N_FRAMES)
    xy = np.c_[0.5 + 0.5 * np.sin(t / 5.0), 2.0 + 3.0 * t / N_FRAMES]
    v = np.gradient(xy, FRAME_S, axis=0)
    frame, state, seen = list(t), list(np.c_[xy, v]), [[True, True]] * N_FRAMES
    for f, node in [(f, 0) for f in s1_frames] + [(f, 1) for f in s2_frames]:
        frame.append(f)
        state.append([-5.0 - xy[f, 0], xy[f, 1], -v[f, 0], v[f, 1]])
        seen.append([node == 0, node == 1])
    k = len(frame)
    poses = np.array([[0.0, 0.0, 0.0], [0.0, 7.0, np.pi]])
    return (np.array(frame), np.array(state), np.tile(np.eye(4) * 0.03 ** 2, (k, 1, 1)),
            np.ones(k, bool), np.array(seen), poses)


def test_two_radars_images_through_one_wall_teach_it_together():
    # 7 frames each: neither radar's images alone make a wall (10 frames).
    few = WALL_MIN_FRAMES - 3
    s1, s2 = range(0, 2 * few, 2), range(1, 2 * few, 2)
    assert learn_walls(*facing_scene(s1, []), body_m=0.5) == []
    assert learn_walls(*facing_scene([], s2), body_m=0.5) == []
    walls = learn_walls(*facing_scene(s1, s2), body_m=0.5)
    assert [w.node for w in walls] == [0, 1]
    for w in walls:
        np.testing.assert_allclose(w.normal, [-1.0, 0.0], atol=0.02)
        assert abs(w.offset_m - 2.5) < 0.05 and w.frames == 2 * few and w.images == few
    # Each image is flagged (beyond the wall of the one node that sees it),
    # the walker kept.
    frame, state, _, ok, seen, poses = facing_scene(s1, s2)
    flag, _ = beyond_learned_walls(state, ok, seen, poses, walls)
    np.testing.assert_array_equal(flag, np.arange(len(frame)) >= N_FRAMES)


def test_a_common_line_both_radars_see_a_person_behind_is_no_wall():
    few = WALL_MIN_FRAMES - 3
    frame, state, cov, ok, seen, poses = facing_scene(range(0, 2 * few, 2),
                                                      range(1, 2 * few, 2))
    # A person both radars see beyond the line, in one frame.
    frame, ok = np.r_[frame, 3], np.r_[ok, True]
    state = np.r_[state, [[-3.5, 3.0, 0.0, 0.5]]]
    cov, seen = np.r_[cov, cov[:1]], np.r_[seen, [[True, True]]]
    assert learn_walls(frame, state, cov, ok, seen, poses, body_m=0.5) == []


# ------------------------------------------------- the simulator's real model
# Its centroid level (the physics of real TI clouds: near-side reflection,
# correlated errors, static clutter centroids, mirror images through the
# room's walls, splits, misses, float16), fused at the true poses with the
# sigmas estimated from the data, as `mmsnap fuse` does by default.

def _real_model_runs(n_targets: int):
    from mmsnap_graph.calibration import estimate_noise
    from mmsnap_graph.fusion.recording.sequence import fuse_recording
    from mmsnap_graph.sim import SimulationOptions, simulate_recording

    rec = simulate_recording("C", "random", SimulationOptions(known_poses=True,
                                                               n_targets=n_targets),
                             levels=("centroids",), n_frames=600, seed=0)
    with np.errstate(invalid="ignore"):
        noise = estimate_noise(rec).per_node
    fused = fuse_recording(rec, config(robust="gate"), noise=noise, progress=False)
    return rec.truth, {w: screen_room(fused, walls=w)[0] for w in (False, True)}


def _truth_seen(truth, fused) -> float:
    """Fraction of the truth's (frame, person) with a kept row within 0.5 m."""
    ok = fused.success
    hit = [np.any(ok & (fused.frame == f)
                  & (np.hypot(*(fused.state[:, :2] - xy).T) <= 0.5))
           for f, xy in zip(truth.frame, truth.state[:, :2])]
    return float(np.mean(hit))


def _ghost_rows(truth, fused) -> int:
    """Kept rows more than 0.5 m from every person of their frame."""
    return sum(np.min(np.hypot(*(truth.state[truth.frame == fused.frame[k], :2]
                                 - fused.state[k, :2]).T)) > 0.5
               for k in np.flatnonzero(fused.success))


@pytest.mark.parametrize("n_targets", [1, 2])
def test_real_model_walkers_kept_and_ghost_rows_dropped(n_targets):
    """Network C: two radars facing each other 7 m apart. Measured (seed 0,
    600 frames): the truth seen within 0.5 m in 99.3% (1 walker) and 95.0%
    (2 walkers) of its frames, with and without the learned walls; kept rows
    more than 0.5 m from every walker (one-node rows of static clutter
    centroids and mirror images) 140 -> 0 and 145 -> 2."""
    truth, runs = _real_model_runs(n_targets)
    seen = {w: _truth_seen(truth, f) for w, f in runs.items()}
    ghosts = {w: _ghost_rows(truth, f) for w, f in runs.items()}
    print(f"{n_targets} walker(s): truth seen {seen}, ghost rows {ghosts}")
    assert seen[True] >= seen[False] - 0.002
    assert ghosts[False] >= 50 and ghosts[True] <= 0.1 * ghosts[False]


# ---------------------------------------- the point clouds' body images, CLI
# Two radars facing each other (network C) see a side wall's images in
# different frames, few per radar (8-9 frames of 600 through one wall): the
# images of both radars teach the wall together.

@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 1])
def test_both_radars_images_teach_a_common_wall(tmp_path, seed):
    """Network C, one walker, 600 frames, the simulator's point clouds with
    the body images, `mmsnap simulate --known-poses`, `process`, `fuse`:
    frames with a kept row more than 1 m from the walker 5.0% and 4.3%
    (seeds 0, 1) with the images counted per radar (no wall learned), 1.7%
    and 0.8% counted together; the walker seen within 0.5 m in 85.5% and
    86.0% of the frames, with and without the learned walls."""
    import shutil

    from mmsnap_graph.app.cli import main
    from mmsnap_graph.io import read_recording
    from mmsnap_graph.io.fused import read_fused

    path = tmp_path / "c.h5"
    assert main(["simulate", "-c", "C", "-t", "random", "-n", "600", "-s", str(seed),
                 "--known-poses", "-o", str(path), "--no-progress"]) == 0
    assert main(["process", str(path), "--no-progress"]) == 0
    off = tmp_path / "off.h5"
    shutil.copy(path, off)
    # the walls alone: the placement check (on by default) flags many of these images too
    assert main(["fuse", str(path), "--no-progress", "--no-placement-check"]) == 0
    assert main(["fuse", str(off), "--no-progress", "--no-learned-walls",
                 "--no-placement-check"]) == 0
    truth = read_recording(path).truth
    frames = np.unique(truth.frame)

    def far_and_seen(fused):
        xy, ok = fused.state[:, :2], fused.success
        far = seen = 0
        for f in frames:
            d = np.hypot(*(xy[ok & (fused.frame == f)] - truth.state[truth.frame == f, :2]).T)
            far += bool(np.any(d > 1.0))
            seen += bool(np.any(d <= 0.5))
        return far / frames.size, seen / frames.size

    (far_on, seen_on), (far_off, seen_off) = far_and_seen(read_fused(path)), far_and_seen(
        read_fused(off))
    print(f"seed {seed}: a kept row > 1 m from the walker in {100 * far_on:.1f}% of the frames "
          f"({100 * far_off:.1f}% without the walls); walker seen in {100 * seen_on:.1f}% "
          f"({100 * seen_off:.1f}%)")
    assert far_on <= 0.02 and far_off >= 0.03          # the images are there and flagged
    assert seen_on >= seen_off - 0.005                 # 3 frames of 600


def _proposals_frame_by_frame(frame, state, cov, ok, image_ok, seen, poses, body_m):
    """The wall proposals one frame at a time (a meshgrid of each frame's
    images and people): the reference of the proposals of every frame at once."""
    from mmsnap_graph.fusion.recording import walls as w

    xy, n_seen, out = state[:, :2], seen.sum(axis=1), []
    order = np.argsort(frame, kind="stable")
    for rows in np.split(order, np.flatnonzero(np.diff(frame[order])) + 1):
        people, images = rows[ok[rows]], rows[image_ok[rows]]
        g, p = (a.ravel() for a in np.meshgrid(images, people, indexing="ij"))
        keep = ((g != p) & (n_seen[g] <= n_seen[p]) & (np.hypot(*(xy[g] - xy[p]).T) >= body_m)
                & (np.hypot(*state[p, 2:].T) >= w.WALL_MOVING_MPS))
        for s in range(poses.shape[0]):
            node = poses[s, :2]
            gs, ps = g[keep & seen[g, s]], p[keep & seen[g, s]]
            far = np.hypot(*(xy[ps] - node).T) < np.hypot(*(xy[gs] - node).T)
            gs, ps = gs[far], ps[far]
            r_g, r_p = np.hypot(*(xy[gs] - node).T), np.hypot(*(xy[ps] - node).T)
            u_g, u_p = (xy[gs] - node) / r_g[:, None], (xy[ps] - node) / r_p[:, None]
            for bounce in (False, True):
                m = node + ((2 * r_g - r_p) / r_g)[:, None] * (xy[gs] - node) if bounce else xy[gs]
                ang, off = w.wall_line(xy[ps], m)
                n = np.stack([np.cos(ang), np.sin(ang)], axis=1)
                k = ((n @ node < off) & (np.einsum("ij,ij->i", n, u_g) > 0)
                     & w.speeds_agree(u_g, u_p, n, state, cov, gs, ps, bounce))
                out.append(np.stack([gs[k], np.full(k.sum(), s), ang[k], off[k],
                                     w.wall_crossing(node, xy[gs], n, off)[k], frame[gs[k]]], axis=1))
    return np.concatenate(out) if out else np.zeros((0, 6))


@pytest.mark.parametrize("seed", [0, 1])
def test_the_proposals_of_all_frames_at_once_are_those_frame_by_frame(seed):
    """Mirror and one-bounce images, a second walker and clutter, rows out of
    frame order: the same proposals, in the same order (frame, node, image
    kind, pair), to rounding (the along-wall position: a matrix product)."""
    from mmsnap_graph.fusion.recording.walls import wall_proposals

    rng = np.random.default_rng(seed)
    frame, xy, v = walker()
    rows = [(f, *p, *u, 2) for f, p, u in zip(frame, xy, v)]
    for image in (mirror, one_bounce):
        g, vg = image(xy, v)
        rows += [(f, *p, *u, 1) for f, p, u in zip(frame, g, vg)]
    rows += [(f, *(xy[f] + [0.8, 0.3]), *-v[f], 2) for f in frame[::3]]
    rows += [(int(rng.integers(N_FRAMES)), *rng.uniform(-3, 5, 2), *rng.normal(0, 1, 2), 1)
             for _ in range(30)]
    r = np.array(rows, dtype=float)[rng.permutation(len(rows))]
    fr = fused_rows(r[:, 0].astype(int), r[:, 1:3], velocity=r[:, 3:5],
                    nodes=r[:, 5].astype(int))
    ok = np.asarray(fr.success)
    image_ok = ok | (rng.random(len(ok)) < 0.1)
    args = (np.asarray(fr.frame), np.asarray(fr.state), np.nan_to_num(np.asarray(fr.covariance)),
            ok, image_ok, np.asarray(fr.observed), np.asarray(fr.node_poses), 0.5)
    want, got = _proposals_frame_by_frame(*args), wall_proposals(*args)
    assert len(want) > 50
    np.testing.assert_array_equal(got[:, [0, 1, 5]], want[:, [0, 1, 5]])
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)


def _near_ref(props, ang, off, scale=1.0):
    """The proposals within ``scale`` times the tolerances of a line."""
    da = np.abs((props[:, 2] - ang + np.pi) % (2 * np.pi) - np.pi)
    return (da <= scale * WALL_ANGLE_TOL_RAD) & (np.abs(props[:, 3] - off)
                                                 <= scale * WALL_OFFSET_TOL_M)


def _best_line_counted(props):
    """(distinct frames, mask of the proposals) of the best-supported line,
    counted from these proposals alone: bins of half the tolerances, each
    bin's neighbourhood (two bins each way) counted in distinct frames by a
    plain loop over the bins, the first of the best bins (angle, then offset)
    taken."""
    bin_rad, bin_m = WALL_ANGLE_TOL_RAD / 2, WALL_OFFSET_TOL_M / 2
    n_a = int(np.ceil(2 * np.pi / bin_rad))
    a = np.floor(props[:, 2] / bin_rad).astype(np.int64) % n_a
    o = np.floor(props[:, 3] / bin_m).astype(np.int64)
    lent: dict[tuple[int, int], set] = {}
    for ai, oi, frame in zip(a, o, props[:, 5]):
        for da in range(-2, 3):
            for do in range(-2, 3):
                lent.setdefault(((ai + da) % n_a, oi + do), set()).add(frame)
    ca, co = min(lent, key=lambda b: (-len(lent[b]), b))
    da = np.abs((a - ca + n_a // 2) % n_a - n_a // 2)
    return len(lent[(ca, co)]), (da <= 2) & (np.abs(o - co) <= 2)


def _lines_counted_again(props, xy, confirmed, poses):
    """The lines of the search, each line counted again from the proposals
    left (_best_line_counted): the reference of the library's updated
    counts, as (angle, offset, proposals, frames, images, distance)."""
    found = []
    while len(props):
        count, mask = _best_line_counted(props)
        if count < WALL_MIN_FRAMES:
            break
        ang = float(np.angle(np.mean(np.exp(1j * props[mask, 2]))))
        off = float(np.median(props[mask, 3]))
        near = _near_ref(props, ang, off)
        explained = np.zeros(len(xy), dtype=bool)
        explained[props[near, 0].astype(np.int64)] = True
        n = np.array([np.cos(ang), np.sin(ang)])
        crossing = confirmed & ~explained & (xy @ n > off)
        if crossing.sum() <= WALL_MAX_CROSSING * confirmed.sum():
            nodes = np.unique(props[near, 1]).astype(np.int64)
            found.append(SimpleNamespace(ang=ang, off=off, props=props[near], frames=count,
                                         images=explained,
                                         dist=off - float(np.max(poses[nodes, :2] @ n))))
        props = props[~(_near_ref(props, ang, off, 2.0) | mask)]
    return found


def _random_proposals(rng, n_lines=12, n_noise=600, n_rows=400, n_frames=300):
    """Proposals (row, node, angle, offset, along, frame) of ``n_lines``
    lines (some near each other, some across the angle's wrap) and noise."""
    out = []
    for _ in range(n_lines):
        ang, off = rng.uniform(-np.pi, np.pi), rng.uniform(0.5, 6.0)
        k = int(rng.integers(5, 80))
        out.append(np.c_[rng.integers(0, n_rows, k), rng.integers(0, 3, k),
                         (ang + rng.normal(0, 0.05, k) + np.pi) % (2 * np.pi) - np.pi,
                         off + rng.normal(0, 0.1, k), rng.uniform(-2, 2, k),
                         rng.integers(0, n_frames, k)])
    out.append(np.c_[rng.integers(0, n_rows, n_noise), rng.integers(0, 3, n_noise),
                     rng.uniform(-np.pi, np.pi, n_noise), rng.uniform(0.2, 8.0, n_noise),
                     rng.uniform(-2, 2, n_noise), rng.integers(0, n_frames, n_noise)])
    props = np.concatenate(out).astype(float)
    return props[np.lexsort((props[:, 1], props[:, 5]))]


@pytest.mark.parametrize("seed", range(6))
def test_lines_with_updated_counts_are_those_counted_again(seed):
    """The line search updates its bins' counts as it takes proposals: the
    same lines, bit for bit (angle, offset, proposals, frames, images,
    distance), as counting the proposals left again for each line; for all
    the proposals and for each node's (counted from the index of all)."""
    from mmsnap_graph.fusion.recording.walls import _LineIndex, _lines

    rng = np.random.default_rng(seed)
    props = _random_proposals(rng)
    # The rows inside the lines but a few, behind some of them.
    xy = rng.uniform(-0.4, 0.4, (400, 2))
    xy[:4] = rng.uniform(-8, 8, (4, 2))
    confirmed = rng.random(400) < (0.3 if seed % 2 else 0.6)
    poses = np.array([[0.0, 0.0, 0.0], [4.0, 0.0, np.pi], [0.0, 4.0, -np.pi / 2]])
    index = _LineIndex(props)
    cases = [(props, index.counts(np.arange(len(props))))]
    for s in range(3):
        rows = np.flatnonzero(props[:, 1] == s)
        cases.append((props[rows], index.counts(rows)))
    n_found = 0
    for p, counts in cases:
        want = _lines_counted_again(p, xy, confirmed, poses)
        for got in (_lines(p, xy, confirmed, poses, counts), _lines(p, xy, confirmed, poses)):
            assert len(got) == len(want)
            for g, w in zip(got, want):
                assert (g.ang, g.off, g.frames, g.dist) == (w.ang, w.off, w.frames, w.dist)
                np.testing.assert_array_equal(g.props, w.props)
                np.testing.assert_array_equal(g.images, w.images)
        n_found += len(want)
    assert n_found >= 3


@pytest.mark.parametrize("image", [mirror, one_bounce])
def test_learned_walls_are_those_of_the_lines_counted_again(image, monkeypatch):
    """learn_walls with the updated counts: the walls of the reference line
    search, exactly."""
    import mmsnap_graph.fusion.recording.walls as w

    rows = scene(image, extra=[(f, 0.5, 5.5, 0.0, 0.3, 1) for f in range(0, N_FRAMES, 2)])
    got = walls_of(rows)
    monkeypatch.setattr(w, "_lines", lambda props, xy, confirmed, poses, counts=None:
                        _lines_counted_again(props, xy, confirmed, poses))
    assert got and got == walls_of(rows)
