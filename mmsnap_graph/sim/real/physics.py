"""What real TI point clouds of people do that a point target does not
(docs/SIMULATOR.md, "Real physics").

:class:`RealPhysics` holds the knobs, calibrated against two public IWR1843
recordings of people walking (``tools/measure_real_recordings.py``); the
functions here apply them to the simulator's centroid and point-cloud
levels:

- **self-occlusion and body size**: a radar sees the near side of a body, so
  its centroid sits ``depth`` metres in front of the body's centre along its
  line of sight; ``depth`` differs from person to person;
- **correlated centroid errors**: a fast part (per-frame scatter of a few
  points, range and cross-range) and a slow part (an AR(1) process with a
  time constant of about 0.7 s: the body's aspect and the points it shows
  change slowly), in the radar's range / cross-range directions;
- **static scene**: zero-Doppler points from walls and furniture (clutter
  removal off, as in TI's out-of-box configurations), at fixed places;
- **multipath ghosts**: mirror images of a person through a wall of the room
  (single centroid rows or points), and at the point-cloud level **body
  images**: a weaker copy of a body's points via a wall, in episodes of
  frames, at the one-bounce (or mirror) path length with its Doppler;
- **split clusters**: one body seen as two clusters;
- **sparse clouds and misses**: a few points per person and frame;
- **quantised values**: local x, y and Doppler rounded to float16, as TI's
  demo sends them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from factors.models import global_to_local, local_to_global, measurement_model, wrap_angle

from ..._validation import check_count
from ...data.recording import Detections
from ...errors import ValidationError
from .sparse import empty_frame_mask

__all__ = ["RealPhysics", "room_box", "person_depths", "correlated_errors", "mirror_through_walls",
           "static_reflectors", "quantize_float16", "physical_centroids", "physical_point_cloud",
           "body_images"]


def _check(name: str, value: float, *, lo: float = 0.0, hi: float = np.inf,
           open_lo: bool = False, open_hi: bool = False) -> None:
    ok = np.isfinite(value) and (value > lo if open_lo else value >= lo) and (
        value < hi if open_hi else value <= hi)
    if not ok:
        raise ValidationError(f"RealPhysics.{name}={value!r} must be in "
                              f"{'(' if open_lo else '['}{lo}, {hi}{')' if open_hi else ']'}")


@dataclass(frozen=True, kw_only=True, slots=True)
class RealPhysics:
    """Knobs of the real physics (SI units; measured values in docs/SIMULATOR.md).

    reflection_depth_m, reflection_depth_std_m : mean and person-to-person
        spread of the near-side offset of a centroid toward each radar
        (drawn once per person, clipped to [0, 2 * mean]). The point-cloud
        level gets it from the body's geometry instead: only torso
        scatterers facing the radar reflect, and ``body_size_std`` scales each
        person's torso (relative standard deviation).
    fast_error_std_m, fast_error_tau_s : (range, cross-range) per-frame
        centroid scatter and its AR(1) time constant (0.3 per 50 ms frame on
        the real recordings; white at 150 ms; 0 = white).
    slow_error_std_m, slow_error_tau_s : the slow AR(1) part of the centroid
        error, per axis (coefficient ``exp(-frame_period / tau)`` per frame).
    p_miss : probability that a person in view gives no centroid / no point
        in a frame.
    points_per_person : Poisson mean of a person's points per frame and node
        (point-cloud level; what the detector found is thinned to it).
    false_alarm_fraction : share of the point-cloud model's false alarms kept.
    split_probability : a person's detection split into two clusters
        ``split_distance_m`` apart (range of a uniform draw); in point clouds
        the splits come in bursts of ``split_frames`` frames on average.
    ghost_probability : centroid level: a person's row mirrored through a
        wall of the room (a multipath image).
    image_fraction, image_episode_frames : point clouds: the share of a
        person's frames, per node, in a multipath episode (a two-state
        Markov chain; episodes last ``image_episode_frames`` on average),
        in which the body's points are seen again via one wall of the room
        (chosen per episode among the walls whose image the node sees);
        0 = no body images.
    image_point_probability : in an episode, each of the body's points
        (after thinning) is copied into the image with this probability.
    image_snr_drop_db : the image's SNR below its body point's.
    image_mirror_share : share of episodes at the mirror image's geometry
        (radar -> wall -> person -> wall -> radar); the others at the
        one-bounce path (radar -> person -> wall -> radar: half the two
        paths' sum, along the mirror image's bearing).
    static_points_per_frame : Poisson mean of zero-Doppler scene points per
        node and frame (point clouds); ``static_centroids_per_frame`` the same
        for static clusters at the centroid level; ``n_static_reflectors``
        fixed places per node (walls, furniture).
    room : ``(x_min, x_max, y_min, y_max)`` of the walls in the global frame;
        None: the box of the nodes and the walking area, ``room_margin_m``
        wider on every side.
    quantize : round local x, y and Doppler to float16.
    """

    reflection_depth_m: float = 0.05
    reflection_depth_std_m: float = 0.015
    body_size_std: float = 0.10
    fast_error_std_m: tuple[float, float] = (0.09, 0.11)
    fast_error_tau_s: float = 0.04
    slow_error_std_m: float = 0.045
    slow_error_tau_s: float = 0.7
    p_miss: float = 0.05
    points_per_person: float = 2.0
    false_alarm_fraction: float = 0.2
    split_probability: float = 0.08
    split_distance_m: tuple[float, float] = (0.3, 0.6)
    split_frames: float = 10.0
    ghost_probability: float = 0.03
    image_fraction: float = 0.45
    image_episode_frames: float = 10.0
    image_point_probability: float = 0.2
    image_snr_drop_db: float = 12.0
    image_mirror_share: float = 0.15
    static_points_per_frame: float = 2.5
    static_centroids_per_frame: float = 1.0
    n_static_reflectors: int = 6
    room: tuple[float, float, float, float] | None = None
    room_margin_m: float = 1.0
    quantize: bool = True

    def __post_init__(self) -> None:
        _check("reflection_depth_m", self.reflection_depth_m, hi=0.5)
        _check("reflection_depth_std_m", self.reflection_depth_std_m, hi=0.5)
        _check("body_size_std", self.body_size_std, hi=0.5)
        if len(self.fast_error_std_m) != 2:
            raise ValidationError(f"RealPhysics.fast_error_std_m={self.fast_error_std_m!r} must "
                                  "be (range_m, cross_range_m)")
        for v in self.fast_error_std_m:
            _check("fast_error_std_m", v, hi=2.0)
        _check("fast_error_tau_s", self.fast_error_tau_s, hi=600.0)
        _check("slow_error_std_m", self.slow_error_std_m, hi=2.0)
        _check("slow_error_tau_s", self.slow_error_tau_s, open_lo=True, hi=600.0)
        _check("p_miss", self.p_miss, hi=1.0, open_hi=True)
        _check("points_per_person", self.points_per_person, open_lo=True, hi=1000.0)
        _check("false_alarm_fraction", self.false_alarm_fraction, hi=1.0)
        _check("split_probability", self.split_probability, hi=0.9)
        _check("split_frames", self.split_frames, lo=1.0, hi=1e4)
        lo, hi = self.split_distance_m
        if not 0 < lo <= hi <= 5:
            raise ValidationError(f"RealPhysics.split_distance_m={self.split_distance_m!r} must "
                                  "be (low, high) metres with 0 < low <= high <= 5")
        _check("ghost_probability", self.ghost_probability, hi=1.0)
        _check("image_fraction", self.image_fraction, hi=0.9)
        _check("image_episode_frames", self.image_episode_frames, lo=1.0, hi=1e4)
        _check("image_point_probability", self.image_point_probability, hi=1.0)
        _check("image_snr_drop_db", self.image_snr_drop_db, hi=100.0)
        _check("image_mirror_share", self.image_mirror_share, hi=1.0)
        _check("static_points_per_frame", self.static_points_per_frame, hi=1000.0)
        _check("static_centroids_per_frame", self.static_centroids_per_frame, hi=1000.0)
        check_count(self.n_static_reflectors, "RealPhysics.n_static_reflectors")
        if self.room is not None:
            x0, x1, y0, y1 = (float(v) for v in self.room)
            if not (np.all(np.isfinite(self.room)) and x0 < x1 and y0 < y1):
                raise ValidationError(f"RealPhysics.room={self.room!r} must be finite "
                                      "(x_min, x_max, y_min, y_max) with min < max")
        _check("room_margin_m", self.room_margin_m, hi=100.0)


def room_box(physics: RealPhysics, node_xy: NDArray, area) -> NDArray:
    """``(x_min, x_max, y_min, y_max)`` of the room's walls."""
    if physics.room is not None:
        return np.asarray(physics.room, dtype=float)
    xs = np.concatenate([node_xy[:, 0], [area.x_min_m, area.x_max_m]])
    ys = np.concatenate([node_xy[:, 1], [area.y_min_m, area.y_max_m]])
    m = physics.room_margin_m
    return np.array([xs.min() - m, xs.max() + m, ys.min() - m, ys.max() + m])


def person_depths(n_people: int, physics: RealPhysics, rng: np.random.Generator) -> NDArray:
    """(n_people,) reflection depths, one per person."""
    d = physics.reflection_depth_m + physics.reflection_depth_std_m * rng.standard_normal(n_people)
    return np.clip(d, 0.0, 2 * physics.reflection_depth_m)


def correlated_errors(n_frames: int, frame_period_s: float, physics: RealPhysics,
                      rng: np.random.Generator, *, fast: bool = True) -> NDArray:
    """(n_frames, 2) (range, cross-range) centroid errors: the slow AR(1)
    part plus (``fast``) the fast AR(1) part, both stationary from the first
    frame."""
    slow = _ar1(n_frames, frame_period_s, physics.slow_error_tau_s,
                np.full(2, physics.slow_error_std_m), rng)
    if not fast:
        return slow
    return slow + _ar1(n_frames, frame_period_s, physics.fast_error_tau_s,
                       np.asarray(physics.fast_error_std_m, dtype=float), rng)


def _ar1(n_frames: int, frame_period_s: float, tau_s: float, std, rng) -> NDArray:
    """(n_frames, 2) stationary AR(1) of standard deviation ``std`` and
    coefficient ``exp(-frame_period_s / tau_s)`` (white for ``tau_s`` 0)."""
    rho = float(np.exp(-frame_period_s / tau_s)) if tau_s > 0 else 0.0
    w = rng.standard_normal((n_frames, 2)) * std
    out = np.empty((n_frames, 2))
    if n_frames:
        out[0] = w[0]
    innov = np.sqrt(1 - rho ** 2)
    for k in range(1, n_frames):
        out[k] = rho * out[k - 1] + innov * w[k]
    return out


def _los(xy: NDArray, node_xy: NDArray) -> tuple[NDArray, NDArray]:
    d = xy - node_xy
    u = d / np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-9)
    return u, np.stack([-u[..., 1], u[..., 0]], axis=-1)


def mirror_through_walls(xy: NDArray, vel: NDArray, room: NDArray) -> tuple[NDArray, NDArray]:
    """Mirror images ``(4, ..., 2)`` of points and their velocities through
    the room's walls (x_min, x_max, y_min, y_max in that order)."""
    ims, vs = [], []
    for axis, wall in ((0, room[0]), (0, room[1]), (1, room[2]), (1, room[3])):
        im, v = xy.copy(), vel.copy()
        im[..., axis] = 2 * wall - xy[..., axis]
        v[..., axis] = -vel[..., axis]
        ims.append(im)
        vs.append(v)
    return np.stack(ims), np.stack(vs)


def static_reflectors(pose: NDArray, room: NDArray, n: int, in_view, rng) -> NDArray:
    """(n, 2) fixed scene reflectors a node sees: on the room's walls and
    (a third of them) furniture inside it, all in the node's view."""
    out: list = []
    for _ in range(200):
        if len(out) >= n:
            break
        if rng.random() < 1 / 3:
            p = np.array([rng.uniform(room[0], room[1]), rng.uniform(room[2], room[3])])
        else:
            wall = rng.integers(4)
            t = rng.random()
            p = np.array([room[0] + t * (room[1] - room[0]), room[2] + t * (room[3] - room[2])])
            p[0 if wall < 2 else 1] = room[wall]
        if in_view(p[None], pose)[0]:
            out.append(p)
    return np.array(out).reshape(-1, 2)


def quantize_float16(det: Detections) -> Detections:
    """Local x, y and Doppler rounded to float16, as TI's demo sends them."""
    theta = np.arcsin(np.clip(det.omega_rad / np.pi, -1, 1))
    x = (det.range_m * np.sin(theta)).astype(np.float16).astype(float)
    y = (det.range_m * np.cos(theta)).astype(np.float16).astype(float)
    r = np.hypot(x, y)
    omega = np.pi * np.divide(x, r, out=np.zeros_like(r), where=r > 0)
    return Detections(frame=det.frame, range_m=r, omega_rad=wrap_angle(omega),
                      doppler_mps=det.doppler_mps.astype(np.float16).astype(float),
                      snr_db=det.snr_db, target_id=det.target_id)


def _measure(xy: NDArray, vel: NDArray, pose: NDArray) -> NDArray:
    h, _ = measurement_model(np.concatenate([xy, vel], axis=-1), pose)
    return h


def _ghost_rows(xy, vel, room, pose, in_view, rng):
    """One mirror image per row, through a random wall whose image the node sees."""
    ims, vs = mirror_through_walls(xy, vel, room)                        # (4, K, 2)
    seen = in_view(ims, pose)                                             # (4, K)
    score = np.where(seen, rng.random(seen.shape), -1.0)
    wall = np.argmax(score, axis=0)
    ok = seen[wall, np.arange(xy.shape[0])]
    k = np.arange(xy.shape[0])
    return ims[wall, k][ok], vs[wall, k][ok], ok


def _one_wall(xy: NDArray, vel: NDArray, room: NDArray, wall: NDArray) -> tuple[NDArray, NDArray]:
    """Mirror images of points (K, 2) and velocities through ``wall`` (K,)
    (0-3: x_min, x_max, y_min, y_max)."""
    k, axis = np.arange(len(xy)), wall // 2
    m, v = xy.copy(), vel.copy()
    m[k, axis] = 2 * room[wall] - xy[k, axis]
    v[k, axis] = -vel[k, axis]
    return m, v


def _image_xy(xy: NDArray, m: NDArray, node_xy: NDArray, mirror: NDArray) -> NDArray:
    """Where the node sees the image of ``xy`` whose mirror image is ``m``:
    ``m`` itself, or (one bounce) half the two paths' sum along ``m``'s bearing."""
    r_p = np.linalg.norm(xy - node_xy, axis=1)
    d = m - node_xy
    r_m = np.maximum(np.linalg.norm(d, axis=1), 1e-9)
    one = node_xy + ((r_p + r_m) / 2 / r_m)[:, None] * d
    return np.where(mirror[:, None], m, one)


def _episode_walls(centre: NDArray, starts: NDArray, pose: NDArray, ctx) -> NDArray:
    """(E,) the wall of each episode: a random one of those whose image of
    the body's centre (at the episode's start) the node sees, among the
    walls along its boresight; -1: none."""
    c = centre[starts]
    ims, _ = mirror_through_walls(c, np.zeros_like(c), ctx.room)             # (4, E, 2)
    seen = np.stack([ctx.in_view(_image_xy(c, ims[w], pose[:2], np.zeros(len(c), bool)), pose)
                     for w in range(4)]) if len(c) else np.zeros((4, 0), bool)
    # Side walls only (along the boresight, within 45 deg), as on the real
    # recordings: a wall facing the radar puts its image further along the
    # person's own bearing, where the chain takes it for the body.
    boresight = local_to_global(np.array([[0.0, 1.0]]), pose)[0] - pose[:2]
    side = np.abs(boresight[[0, 0, 1, 1]]) < np.sqrt(0.5)
    seen &= side[:, None]
    score = np.where(seen, ctx.image_rng.random(seen.shape), -1.0)
    wall = np.argmax(score, axis=0)
    return np.where(seen[wall, np.arange(len(c))], wall, -1)


def body_images(xy: NDArray, frame: NDArray, tid: NDArray, dop: NDArray, snr: NDArray,
                pose: NDArray, n_frames: int, ctx) -> tuple[NDArray, NDArray, NDArray, NDArray]:
    """Multipath images of the bodies in one node's point cloud: ``(xy (G, 2),
    frame, doppler, snr)``.

    Per person, episodes of frames (:func:`empty_frame_mask` with
    ``image_fraction`` and ``image_episode_frames``) in which each of the
    body's points (``xy`` global, ``tid`` >= 0) is copied with probability
    ``image_point_probability`` through the episode's wall: at the one-bounce
    path (or, in ``image_mirror_share`` of the episodes, the mirror image),
    with the Doppler of that path (the point's own plus the change the path
    makes to the body centre's: all of it for the mirror image, half of it
    for one bounce) and ``image_snr_drop_db`` less SNR. Images the node does
    not see are dropped.
    """
    ph, rng = ctx.physics, ctx.image_rng
    out = [(np.zeros((0, 2)), np.zeros(0, np.int64), np.zeros(0), np.zeros(0))]
    if ph.image_fraction <= 0 or ctx.states is None:
        return out[0]
    for t in np.unique(tid[tid >= 0]):
        on = empty_frame_mask(n_frames, ph.image_fraction, ph.image_episode_frames, rng)
        first = on & ~np.r_[False, on[:-1]]
        episode = np.cumsum(first) - 1
        centre, vel = ctx.states[t, :, :2], ctx.states[t, :, 2:]
        wall = _episode_walls(centre, np.flatnonzero(first), pose, ctx)
        mirror = rng.random(wall.size) < ph.image_mirror_share
        rows = np.flatnonzero((tid == t) & on[frame])
        rows = rows[rng.random(rows.size) < ph.image_point_probability]
        rows = rows[wall[episode[frame[rows]]] >= 0]
        f, e = frame[rows], episode[frame[rows]]
        w, mir = wall[e], mirror[e]
        m, _ = _one_wall(xy[rows], np.zeros((rows.size, 2)), ctx.room, w)
        img = _image_xy(xy[rows], m, pose[:2], mir)
        mc, mv = _one_wall(centre[f], vel[f], ctx.room, w)
        d_p = _measure(centre[f], vel[f], pose)[..., 2]
        d_m = _measure(mc, mv, pose)[..., 2]
        d = dop[rows] + np.where(mir, 1.0, 0.5) * (d_m - d_p)
        seen = ctx.in_view(img, pose) if rows.size else np.zeros(0, bool)
        out.append((img[seen], f[seen], d[seen], snr[rows][seen] - ph.image_snr_drop_db))
    return tuple(np.concatenate(c) for c in zip(*out))


def physical_centroids(states: NDArray, pose: NDArray, depths: NDArray, ctx) -> Detections:
    """Centroid level with the real physics (module doc) for one node.

    states : (T, F, 4) torso states; depths : (T,) reflection depths;
    ctx : :class:`PhysicsContext` of the node.
    """
    ph, rng = ctx.physics, ctx.rng
    n_t, n_f, _ = states.shape
    node_xy = pose[:2]
    rows_f, rows_t, rows_xy, rows_v = [], [], [], []
    for t in range(n_t):
        xy, vel = states[t, :, :2], states[t, :, 2:]
        u, v = _los(xy, node_xy)
        e = correlated_errors(n_f, ctx.frame_period_s, ph, rng)
        seen = ctx.in_view(xy, pose) & (rng.random(n_f) >= ph.p_miss)
        shifted = xy + (e[:, :1] - depths[t]) * u + e[:, 1:] * v
        f = np.flatnonzero(seen)
        split = rng.random(f.size) < ph.split_probability
        d = rng.uniform(*ph.split_distance_m, split.sum()) / 2
        ang = rng.uniform(0, 2 * np.pi, split.sum())
        off = d[:, None] * np.stack([np.cos(ang), np.sin(ang)], axis=1)
        fs = f[split]
        rows_f += [f[~split], fs, fs]
        rows_t += [np.full(f.size + fs.size, t)]
        rows_xy += [shifted[f[~split]], shifted[fs] + off, shifted[fs] - off]
        rows_v += [vel[f[~split]], vel[fs], vel[fs]]
    frame = np.concatenate(rows_f).astype(np.int64) if rows_f else np.zeros(0, np.int64)
    tid = np.concatenate(rows_t) if rows_t else np.zeros(0, np.int64)
    xy = np.concatenate(rows_xy).reshape(-1, 2)
    vel = np.concatenate(rows_v).reshape(-1, 2)
    # Multipath: a mirror image of a detected body through a wall.
    g = rng.random(frame.size) < ph.ghost_probability
    gxy, gv, ok = _ghost_rows(xy[g], vel[g], ctx.room, pose, ctx.in_view, rng)
    # Static scene clusters: zero Doppler, at the node's fixed reflectors.
    refl = ctx.reflectors
    n_s = rng.poisson(ph.static_centroids_per_frame, n_f) if refl.size else np.zeros(n_f, int)
    s_frame = np.repeat(np.arange(n_f), n_s)
    s_xy = refl[rng.integers(0, max(len(refl), 1), s_frame.size)] + 0.02 * rng.standard_normal(
        (s_frame.size, 2)) if s_frame.size else np.zeros((0, 2))
    all_xy = np.concatenate([xy, gxy, s_xy])
    all_v = np.concatenate([vel, gv, np.zeros_like(s_xy)])
    h = _measure(all_xy, all_v, pose) if all_xy.size else np.zeros((0, 3))
    h[: frame.size, 2] += ctx.doppler_std_mps * rng.standard_normal(frame.size)
    h[frame.size + gxy.shape[0]:, 2] = 0.0
    frames = np.concatenate([frame, frame[g][ok], s_frame])
    tids = np.concatenate([tid, np.full(gxy.shape[0] + s_frame.size, -1)])
    snr = np.concatenate([ctx.snr_db(tid, frame), ctx.snr_db(tid[g][ok], frame[g][ok]) - 6.0,
                          np.full(s_frame.size, ctx.threshold_db + 3.0)])
    order = np.lexsort((tids, frames))
    det = Detections(frame=frames[order], range_m=h[order, 0], omega_rad=wrap_angle(h[order, 1]),
                     doppler_mps=h[order, 2], snr_db=snr[order], target_id=tids[order])
    return quantize_float16(det) if ph.quantize else det


def self_occluded(centre_xy: NDArray, positions_m: NDArray, torso: NDArray,
                  node_xy: NDArray) -> NDArray:
    """(F, M) bool: torso scatterers on the far side of the body from the node.

    centre_xy : (F, 2) torso centres; positions_m : (F, M, 2); torso : (M,) bool.
    """
    out_n = positions_m - centre_xy[:, None, :]
    to_node = node_xy - centre_xy
    return (np.einsum("fmk,fk->fm", out_n, to_node) < 0) & torso[None, :]


def body_shift(n_frames: int, centre_xy: NDArray, node_xy: NDArray, ctx) -> NDArray:
    """(F, 2) slow correlated shift of one person's points seen by one node."""
    e = correlated_errors(n_frames, ctx.frame_period_s, ctx.physics, ctx.rng, fast=False)
    u, v = _los(centre_xy, node_xy)
    return e[:, :1] * u + e[:, 1:] * v


def physical_point_cloud(det: Detections, pose: NDArray, n_frames: int, ctx) -> Detections:
    """Thin, split, add body images and the static scene to one node's point cloud
    (the detector's points of the bodies, already self-occluded and shifted)."""
    ph, rng = ctx.physics, ctx.rng
    person = det.target_id >= 0
    keep = ~person & (rng.random(len(det)) < ph.false_alarm_fraction)
    # Sparse: a Poisson number of each person's points per frame, none in a
    # missed frame, drawn with probability proportional to their power (the
    # torso's points are stronger than the limbs').
    idx = np.flatnonzero(person)
    key = det.frame[idx] * 1000 + det.target_id[idx]
    power = 10 ** ((det.snr_db[idx] - det.snr_db[idx].max(initial=0)) / 10)
    order = idx[np.lexsort((rng.exponential(1.0, idx.size) / power, key))]
    key = det.frame[order] * 1000 + det.target_id[order]
    start = np.r_[0, np.flatnonzero(np.diff(key)) + 1]
    counts = np.diff(np.r_[start, key.size])
    want = rng.poisson(ph.points_per_person, start.size) * (rng.random(start.size) >= ph.p_miss)
    rank = np.arange(key.size) - np.repeat(start, counts)
    keep[order[rank < np.repeat(want, counts)]] = True
    sel = np.flatnonzero(keep)
    local = np.stack([det.range_m[sel] * np.sin(np.arcsin(det.omega_rad[sel] / np.pi)),
                      det.range_m[sel] * np.cos(np.arcsin(det.omega_rad[sel] / np.pi))], axis=1)
    xy = local_to_global(local, pose)
    frame, tid = det.frame[sel], det.target_id[sel]
    dop, snr = det.doppler_mps[sel], det.snr_db[sel]
    # Split: half of a person's points moved away as a second cluster, in
    # bursts of frames (a limb or a body part that stays apart for a while).
    for t in np.unique(tid[tid >= 0]):
        burst = empty_frame_mask(n_frames, ph.split_probability, ph.split_frames, rng)
        start = np.cumsum(burst & ~np.r_[False, burst[:-1]])
        ang = rng.uniform(0, 2 * np.pi, start[-1] + 1 if n_frames else 1)
        dist = rng.uniform(*ph.split_distance_m, ang.size)
        for f in np.flatnonzero(burst):
            rows = np.flatnonzero((frame == f) & (tid == t))
            b = start[f]
            xy[rows[: rows.size // 2]] += dist[b] * np.array([np.cos(ang[b]), np.sin(ang[b])])
    # Static scene points: zero Doppler, at the node's reflectors.
    refl = ctx.reflectors
    n_s = rng.poisson(ph.static_points_per_frame, n_frames) if refl.size else np.zeros(n_frames, int)
    s_frame = np.repeat(np.arange(n_frames), n_s)
    s_xy = (refl[rng.integers(0, max(len(refl), 1), s_frame.size)]
            + 0.03 * rng.standard_normal((s_frame.size, 2)))
    # Multipath: a weaker copy of a body's points via a wall, in episodes.
    i_xy, i_frame, i_dop, i_snr = body_images(xy, frame, tid, dop, snr, pose, n_frames, ctx)
    all_xy = np.concatenate([xy, s_xy, i_xy])
    loc = global_to_local(all_xy, pose)
    r = np.hypot(loc[:, 0], loc[:, 1])
    omega = np.pi * loc[:, 0] / np.maximum(r, 1e-9)
    frames = np.concatenate([frame, s_frame, i_frame])
    dops = np.concatenate([dop, np.zeros(s_frame.size), i_dop])
    snrs = np.concatenate([snr, ctx.threshold_db + rng.exponential(3.0, s_frame.size), i_snr])
    tids = np.concatenate([tid, np.full(s_frame.size + i_frame.size, -1)])
    order = np.argsort(frames, kind="stable")
    out = Detections(frame=frames[order], range_m=r[order], omega_rad=wrap_angle(omega[order]),
                     doppler_mps=dops[order], snr_db=snrs[order], target_id=tids[order])
    return quantize_float16(out) if ph.quantize else out


@dataclass(frozen=True, slots=True)
class PhysicsContext:
    """What the physics of one node needs from the simulator."""

    physics: RealPhysics
    rng: np.random.Generator
    frame_period_s: float
    room: NDArray
    reflectors: NDArray
    in_view: object
    snr_db: object
    threshold_db: float
    doppler_std_mps: float
    states: NDArray | None = None
    image_rng: np.random.Generator | None = None
