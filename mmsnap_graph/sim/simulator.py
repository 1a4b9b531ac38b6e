"""Simulated recordings of walking humans seen by a radar network
(docs/SIMULATOR.md).

:func:`simulate_recording` builds a :class:`~mmsnap_graph.data.recording.Recording`
with its :class:`~mmsnap_graph.data.recording.Truth` (torso states of every target
and the true node poses) and any of three levels per node:

- ``"centroids"``: one row per target per frame in view: the torso's
  measurement :func:`factors.models.measurement_model` plus Gaussian noise
  (:data:`CENTROID_NOISE` by default), optional missed detections
  (``centroid_p_miss``);
- ``"point_cloud"``: one detection per resolvable body scatterer (torso,
  arms, legs: limb micro-Doppler), detected with a probability from its SNR,
  with SNR-dependent noise, plus false alarms (:class:`PointCloudModel`); a
  statistical model of the FFT + CFAR chain, not the chain itself;
- ``"cube"``: raw ADC cubes synthesized by :mod:`mmsnap_graph.sim.cube` from
  the body scatterers, thermal noise and static clutter (:class:`CubeModel`).

Random streams are derived from ``seed`` per purpose and per node, so adding
or removing a level leaves the other levels unchanged.
"""

from __future__ import annotations

import dataclasses
import os
import tempfile
from dataclasses import dataclass
from typing import Iterable, Mapping, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray
from tqdm import tqdm

from factors.models import global_to_local, measurement_model, wrap_angle

from ..errors import ValidationError
from ..data.noise import MeasurementNoise
from ..data.radar_config import TABLE_I, RadarConfig
from ..data.recording import Detections, NodeData, Recording, Truth
from .._validation import as_float_array, check_count, check_finite
from .body import BodyScatterers, HumanBody, body_scatterers
from .cube import post_fft_snr_db, scatterer_amplitude, synthesize_cubes
from .networks import (
    Area,
    DEFAULT_FOV_RAD,
    DEFAULT_MAX_RANGE_M,
    DEFAULT_MIN_RANGE_M,
    common_area,
    in_field_of_view,
    network_poses,
)
from .options import (CENTROID_NOISE, CLEAN, DEFAULT_LEVELS, LEVELS, CubeModel, PointCloudModel,
                      SimulationOptions)
from .real.physics import (PhysicsContext, body_shift, person_depths, physical_centroids,
                      physical_point_cloud, room_box, self_occluded, static_reflectors)
from .trajectories import DEFAULT_N_FRAMES, TRAJECTORY_KINDS, RandomWalkOptions, make_trajectory

__all__ = ["LEVELS", "DEFAULT_LEVELS", "CENTROID_NOISE", "PointCloudModel", "CubeModel",
           "SimulationOptions", "CLEAN", "simulate_recording", "simulate_targets"]

# Stream identifiers for the derived random generators.
_TRAJECTORY, _BODY, _CENTROIDS, _POINT_CLOUD, _CUBE, _CLUTTER, _PHYSICS, _PEOPLE, _IMAGES = range(9)


def _stream(seed: int, purpose: int, index: int = 0) -> np.random.Generator:
    return np.random.default_rng([int(seed), purpose, index])


# --------------------------------------------------------------------------
def simulate_targets(network: str | Mapping[str, ArrayLike], trajectory: str | ArrayLike = "straight",
                     *, n_targets: int = 1, n_frames: int = DEFAULT_N_FRAMES,
                     frame_period_s: float = TABLE_I.frame_period_s, seed: int = 0,
                     walk: RandomWalkOptions | None = None, **straight_options) -> NDArray:
    """Torso states ``(n_targets, F, 4)`` of the targets, global frame.

    ``trajectory`` is a kind (``"straight"``, ``"random"``; each target gets
    its own random stream) or explicit states ``(F, 4)`` or
    ``(n_targets, F, 4)`` (then ``n_targets`` and ``n_frames`` follow them).
    """
    if isinstance(trajectory, str):
        if trajectory not in TRAJECTORY_KINDS:
            raise ValidationError(f"trajectory={trajectory!r} must be one of "
                                  f"{TRAJECTORY_KINDS} or an array of states")
        check_count(n_targets, "n_targets")
        area = common_area(network)
        return np.stack([make_trajectory(trajectory, area, n_frames=n_frames,
                                         frame_period_s=frame_period_s,
                                         rng=_stream(seed, _TRAJECTORY, t), walk=walk,
                                         **straight_options)
                         for t in range(int(n_targets))])
    states = check_finite(as_float_array(trajectory, "trajectory"), "trajectory")
    if states.ndim == 2:
        states = states[None]
    if states.ndim != 3 or states.shape[2] != 4 or states.shape[1] < 1:
        raise ValidationError(f"trajectory states must have shape (F, 4) or (n_targets, F, 4), "
                              f"got {np.shape(trajectory)}")
    return states


def _in_view(points, pose, limits) -> NDArray:
    return in_field_of_view(points, pose, **limits)


def _centroids(states: NDArray, pose: NDArray, noise: MeasurementNoise, p_miss: float, limits,
               rng: np.random.Generator, snr_db: NDArray) -> Detections:
    n_t, n_f, _ = states.shape
    h, _ = measurement_model(states, pose)                                   # (T, F, 3)
    visible = _in_view(states[..., :2], pose, limits)
    z = h + rng.standard_normal(h.shape) * noise.sigmas
    keep = visible & (rng.random(visible.shape) >= p_miss)
    tid, frame = np.nonzero(keep)
    order = np.lexsort((tid, frame))
    tid, frame = tid[order], frame[order]
    zz = z[tid, frame]
    return Detections(frame=frame, range_m=np.abs(zz[:, 0]), omega_rad=wrap_angle(zz[:, 1]),
                      doppler_mps=zz[:, 2], snr_db=snr_db[tid, frame], target_id=tid)


def _detection_snr_db(radar: RadarConfig, rcs_m2: NDArray, range_m: NDArray,
                      noise_std: float) -> NDArray:
    amp = scatterer_amplitude(radar, rcs_m2, np.maximum(range_m, 1e-3), noise_std=noise_std)
    return post_fft_snr_db(radar, amp, noise_std) + 10 * np.log10(radar.n_virtual)


def _point_cloud(bodies: Sequence[BodyScatterers], pose: NDArray, radar: RadarConfig,
                 model: PointCloudModel, limits, rng: np.random.Generator,
                 hidden: Sequence[NDArray] | None = None) -> Detections:
    """The detector's points of the bodies; ``hidden`` (per body, (F, M)
    bool) masks scatterers the node cannot see (self-occlusion)."""
    n_f = bodies[0].positions_m.shape[0]
    rows = []
    for tid, b in enumerate(bodies):
        m = b.positions_m.shape[1]
        st = np.concatenate([b.positions_m, b.velocities_mps], axis=-1)     # (F, M, 4)
        h, _ = measurement_model(st, pose)                                   # (F, M, 3)
        # Scatterers without RCS (e.g. a body with limbs switched off) reflect nothing.
        vis = _in_view(b.positions_m, pose, limits) & (b.rcs_m2 > 0)[None, :]
        if hidden is not None:
            vis &= ~hidden[tid]
        snr = _detection_snr_db(radar, np.broadcast_to(b.rcs_m2, (n_f, m)), h[..., 0],
                                model.noise_std)
        f_idx, m_idx = np.nonzero(vis)
        rows.append((np.full(f_idx.size, tid), f_idx, h[f_idx, m_idx], snr[f_idx, m_idx]))
    tid = np.concatenate([r[0] for r in rows])
    frame = np.concatenate([r[1] for r in rows])
    h = np.concatenate([r[2] for r in rows])
    snr = np.concatenate([r[3] for r in rows])
    # Merge scatterers of one target in one (range, Doppler, angle) cell.
    d_r, d_v = radar.range_resolution_m, radar.doppler_resolution_mps
    d_w = 2 * np.pi / model.angle_fft_size
    keys = np.stack([frame, tid, np.floor(h[:, 0] / d_r), np.floor(h[:, 2] / d_v),
                     np.floor(h[:, 1] / d_w)], axis=1).astype(np.int64)
    strongest = np.argsort(-snr, kind="stable")
    _, first = np.unique(keys[strongest], axis=0, return_index=True)
    sel = strongest[first]
    tid, frame, h, snr = tid[sel], frame[sel], h[sel], snr[sel]
    # Detection (Swerling 1): Pd = Pfa ** (1 / (1 + snr)).
    snr_lin = 10 ** (snr / 10)
    pd = model.p_false_alarm ** (1 / (1 + snr_lin)) * (1 - model.p_miss)
    hit = rng.random(pd.shape) < pd
    tid, frame, h, snr, snr_lin = tid[hit], frame[hit], h[hit], snr[hit], snr_lin[hit]
    res = np.array([d_r, radar.omega_resolution_rad, d_v])
    bins = np.array([d_r, d_w, d_v])
    sigma = np.sqrt(bins ** 2 / 12 + res ** 2 / (2 * snr_lin[:, None]))
    z = h + sigma * rng.standard_normal(h.shape)
    v_max = radar.max_doppler_mps
    z[:, 2] = (z[:, 2] + v_max) % (2 * v_max) - v_max
    z[:, 1] = wrap_angle(z[:, 1])
    z[:, 0] = np.abs(z[:, 0])
    snr_meas = snr + model.snr_std_db * rng.standard_normal(snr.shape)
    # False alarms.
    n_fa = rng.poisson(model.false_alarms_per_frame, n_f)
    fa_frame = np.repeat(np.arange(n_f), n_fa)
    k = fa_frame.size
    w_max = np.pi * np.sin(limits["fov_rad"])
    fa = np.stack([rng.uniform(limits["min_range_m"], limits["max_range_m"], k),
                   rng.uniform(-w_max, w_max, k), rng.uniform(-v_max, v_max, k)], axis=1)
    fa_snr = model.threshold_db + rng.exponential(1.5, k)
    frame = np.concatenate([frame, fa_frame])
    z = np.concatenate([z, fa])
    snr_all = np.concatenate([snr_meas, fa_snr])
    tid = np.concatenate([tid, np.full(k, -1)])
    order = np.argsort(frame, kind="stable")
    return Detections(frame=frame[order], range_m=z[order, 0], omega_rad=z[order, 1],
                      doppler_mps=z[order, 2], snr_db=snr_all[order], target_id=tid[order])


def _clutter(radar: RadarConfig, model: CubeModel, limits, rng: np.random.Generator):
    n = int(model.n_clutter)
    if n == 0:
        return None
    r = rng.uniform(model.clutter_min_range_m, min(model.clutter_max_range_m,
                                                   0.95 * radar.max_range_m), n)
    theta = rng.uniform(-limits["fov_rad"], limits["fov_rad"], n)
    lo, hi = model.clutter_rcs_m2
    rcs = np.exp(rng.uniform(np.log(lo), np.log(hi), n))
    amp = scatterer_amplitude(radar, rcs, r, noise_std=max(model.noise_std, 1e-12))
    phase = np.exp(2j * np.pi * rng.random(n))
    return np.stack([r * np.sin(theta), r * np.cos(theta)], axis=1), amp * phase


def _cube_inputs(bodies: Sequence[BodyScatterers], pose: NDArray, radar: RadarConfig,
                 model: CubeModel, frames: NDArray, limits):
    pos_l, vel_l, amp_l = [], [], []
    c, s = np.cos(pose[2]), np.sin(pose[2])
    rot = np.array([[c, s], [-s, c]])                     # global -> local rotation
    noise_ref = max(model.noise_std, 1e-12)
    for f in frames:
        p = np.concatenate([b.positions_m[f] for b in bodies])
        v = np.concatenate([b.velocities_mps[f] for b in bodies])
        rcs = np.concatenate([b.rcs_m2 for b in bodies])
        vis = _in_view(p, pose, limits) & (rcs > 0)
        pl = global_to_local(p[vis], pose)
        vl = v[vis] @ rot.T
        r = np.hypot(pl[:, 0], pl[:, 1])
        # The carrier phase 4 pi R / lambda of each scatterer, folded into the
        # complex amplitude with the sign sim.cube's Doppler term implies
        # (exp(+j 4 pi R / lambda)), so the phase stays coherent across frames.
        amp = (scatterer_amplitude(radar, rcs[vis], r, noise_std=noise_ref)
               * np.exp(4j * np.pi * r / radar.wavelength_m))
        pos_l.append(pl)
        vel_l.append(vl)
        amp_l.append(amp)
    return pos_l, vel_l, amp_l


def _cubes(bodies, pose, radar, model, frames, limits, rng, clutter_rng, progress_bar,
           memmap_dir, node_name) -> NDArray:
    clutter = _clutter(radar, model, limits, clutter_rng)
    shape = (frames.size, *radar.cube_shape)
    if memmap_dir is not None:
        fd, tmp = tempfile.mkstemp(prefix=f"cube_{node_name}_", suffix=".c64", dir=memmap_dir)
        os.close(fd)
        out = np.memmap(tmp, dtype=np.complex64, mode="w+", shape=shape)
    else:
        out = np.empty(shape, dtype=np.complex64)
    chunk = 8
    for start in range(0, frames.size, chunk):
        sl = slice(start, min(start + chunk, frames.size))
        pos, vel, amp = _cube_inputs(bodies, pose, radar, model, frames[sl], limits)
        block = out[sl]
        synthesize_cubes(radar, pos, vel, amp, rng=rng, noise_std=model.noise_std,
                         clutter=clutter, out=block)
        if model.quantize:
            view = block.view(np.float32)
            np.round(view, out=view)
            np.clip(view, -32768, 32767, out=view)
        if progress_bar is not None:
            progress_bar.update(sl.stop - sl.start)
    return out


def _cube_frame_numbers(cube_frames, n_f: int) -> NDArray:
    """The frames that get a raw cube (see :func:`simulate_recording`)."""
    if cube_frames is None:
        return np.arange(n_f)
    if np.ndim(cube_frames) == 0:
        check_count(cube_frames, "cube_frames", 0, n_f)
        return np.arange(int(cube_frames))
    frames_c = np.asarray(cube_frames)
    if (frames_c.ndim != 1 or not np.issubdtype(frames_c.dtype, np.integer)
            or np.any(frames_c < 0) or np.any(frames_c >= n_f)):
        raise ValidationError(f"cube_frames must be frame numbers in [0, {n_f}), "
                              f"got {cube_frames!r}")
    return frames_c



@dataclass(frozen=True, slots=True)
class _Setup:
    """Everything a node's simulation needs besides its pose and index."""

    levels: tuple
    options: SimulationOptions
    radar: RadarConfig
    states: NDArray
    bodies: list
    limits: dict
    seed: int
    frames_c: NDArray
    cube_memmap_dir: object
    room: NDArray | None
    depths: NDArray | None


def _physics_context(setup: _Setup, i: int, pose: NDArray, torso_snr) -> PhysicsContext:
    ph = setup.options.physics
    rng = _stream(setup.seed, _PHYSICS, i)
    in_view = lambda p, q: _in_view(p, q, setup.limits)  # noqa: E731
    return PhysicsContext(
        physics=ph, rng=rng, frame_period_s=setup.radar.frame_period_s, room=setup.room,
        reflectors=static_reflectors(pose, setup.room, ph.n_static_reflectors, in_view, rng),
        in_view=in_view, snr_db=lambda tid, frame: torso_snr[tid, frame],
        threshold_db=setup.options.point_cloud_model.threshold_db,
        doppler_std_mps=setup.options.centroid_noise.doppler_mps, states=setup.states,
        image_rng=_stream(setup.seed, _IMAGES, i))


def _physical_bodies(setup: _Setup, pose: NDArray, ctx: PhysicsContext):
    """The bodies as one node sees them: shifted by its slow correlated error,
    with the torso's far side hidden."""
    bodies, hidden = [], []
    torso = setup.bodies[0].part == 0
    for t, b in enumerate(setup.bodies):
        centre = setup.states[t, :, :2]
        shift = body_shift(centre.shape[0], centre, pose[:2], ctx)
        bodies.append(dataclasses.replace(b, positions_m=b.positions_m + shift[:, None, :]))
        hidden.append(self_occluded(centre, b.positions_m, torso, pose[:2]))
    return bodies, hidden


def _simulate_node(setup: _Setup, i: int, name: str, pose: NDArray, bar) -> NodeData:
    """One node's levels, each from its own random stream."""
    radar, states, seed, opt = setup.radar, setup.states, setup.seed, setup.options
    n_t, n_f, _ = states.shape
    kw = {"name": name, "radar": radar, "pose": pose if opt.known_poses else None}
    torso_snr = np.stack([
        _detection_snr_db(radar, np.full(n_f, opt.body.torso_rcs_m2),
                          measurement_model(states[t], pose)[0][:, 0],
                          opt.point_cloud_model.noise_std) for t in range(n_t)])
    ctx = None if opt.physics is None else _physics_context(setup, i, pose, torso_snr)
    if "centroids" in setup.levels:
        if ctx is None:
            kw["centroids"] = _centroids(states, pose, opt.centroid_noise, opt.centroid_p_miss,
                                         setup.limits, _stream(seed, _CENTROIDS, i), torso_snr)
        else:
            kw["centroids"] = physical_centroids(states, pose, setup.depths, ctx)
    if "point_cloud" in setup.levels:
        if ctx is None:
            kw["point_cloud"] = _point_cloud(setup.bodies, pose, radar, opt.point_cloud_model,
                                             setup.limits, _stream(seed, _POINT_CLOUD, i))
        else:
            bodies, hidden = _physical_bodies(setup, pose, ctx)
            det = _point_cloud(bodies, pose, radar, opt.point_cloud_model, setup.limits,
                               _stream(seed, _POINT_CLOUD, i), hidden)
            kw["point_cloud"] = physical_point_cloud(det, pose, n_f, ctx)
    if "cube" in setup.levels:
        kw["cube"] = _cubes(setup.bodies, pose, radar, opt.cube_model, setup.frames_c,
                            setup.limits, _stream(seed, _CUBE, i), _stream(seed, _CLUTTER, i),
                            bar, setup.cube_memmap_dir, name)
        kw["cube_frame"] = setup.frames_c
    return NodeData(**kw)


def _metadata(network, trajectory, setup: _Setup) -> dict:
    noise = setup.options.centroid_noise
    return {
        "generator": "mmsnap_graph.sim.simulate_recording",
        "network": network if isinstance(network, str) else "custom",
        "trajectory": trajectory if isinstance(trajectory, str) else "given",
        "seed": int(setup.seed),
        "n_targets": int(setup.states.shape[0]),
        "levels": ",".join(setup.levels),
        "model": "clean" if setup.options.physics is None else "real",
        "fov_rad": setup.limits["fov_rad"],
        "max_range_m": setup.limits["max_range_m"],
        "min_range_m": setup.limits["min_range_m"],
        "centroid_range_std_m": noise.range_m,
        "centroid_omega_std_rad": noise.omega_rad,
        "centroid_doppler_std_mps": noise.doppler_mps,
        # Each person's near-side offset of the centroid level (real physics).
        **({} if setup.depths is None else {"reflection_depth_m": setup.depths.copy()}),
    }


def _check_levels(levels) -> tuple[str, ...]:
    levels = (levels,) if isinstance(levels, str) else tuple(levels)
    bad = [lv for lv in levels if lv not in LEVELS]
    if bad or not levels:
        raise ValidationError(f"levels={levels!r} must be a non-empty subset of {LEVELS}")
    return levels


def _bodies(states: NDArray, frame_period_s: float, opt: SimulationOptions, seed: int) -> list:
    """One body per target; with physics each person has their own size."""
    n_t = states.shape[0]
    scale = np.ones(n_t)
    if opt.physics is not None:
        rng = _stream(seed, _PEOPLE, 1)
        scale = np.clip(1 + opt.physics.body_size_std * rng.standard_normal(n_t), 0.6, 1.4)
    out = []
    for t in range(n_t):
        body = opt.body if scale[t] == 1 else dataclasses.replace(
            opt.body, torso_half_width_m=opt.body.torso_half_width_m * scale[t],
            torso_half_depth_m=opt.body.torso_half_depth_m * scale[t])
        out.append(body_scatterers(states[t], frame_period_s, body=body,
                                   rng=_stream(seed, _BODY, t)))
    return out


def simulate_recording(
    network: str | Mapping[str, ArrayLike] = "C",
    trajectory: str | ArrayLike = "straight",
    options: SimulationOptions | None = None,
    *,
    levels: Iterable[str] = DEFAULT_LEVELS,
    n_frames: int = DEFAULT_N_FRAMES,
    seed: int = 0,
    progress: bool = False,
    cube_memmap_dir: str | os.PathLike | None = None,
) -> Recording:
    """Simulate a recording of walking humans.

    network : ``"A"``, ``"B"``, ``"C"`` or a mapping ``name -> (3,) pose``
        (first = reference S1).
    trajectory : ``"straight"``, ``"random"`` or states ``(F, 4)`` /
        ``(n_targets, F, 4)`` (global frame, torso).
    options : :class:`SimulationOptions` (default: the real physics on, one
        target, Table I radars); :data:`CLEAN` for the clean model.
    levels : any of ``"centroids"``, ``"point_cloud"``, ``"cube"`` (default
        the first two: a Table I raw cube is 5.9 MB per node and frame).
    n_frames : length (600 frames of the radar's 150 ms = 90 s).
    seed : all randomness derives from it (per purpose and node).
    progress : show a tqdm bar over the cube synthesis.
    cube_memmap_dir : if given, cubes are built in memory-mapped files in that
        folder (for long cube recordings); the caller deletes the files.
    Returns the :class:`Recording` with truth and metadata (``model``:
    ``"real"`` or ``"clean"``).
    """
    opt = SimulationOptions() if options is None else options
    if not isinstance(opt, SimulationOptions):
        raise ValidationError(f"options must be a SimulationOptions, got {type(opt).__name__}")
    levels = _check_levels(levels)
    radar = opt.radar
    frame_period_s = radar.frame_period_s if opt.frame_period_s is None else opt.frame_period_s
    if frame_period_s != radar.frame_period_s:
        radar = dataclasses.replace(radar, frame_period_s=float(frame_period_s))
    poses = network_poses(network)
    states = simulate_targets(network, trajectory, n_targets=opt.n_targets, n_frames=n_frames,
                              frame_period_s=frame_period_s, seed=seed,
                              walk=opt.trajectory_options)
    n_t, n_f, _ = states.shape
    limits = dict(fov_rad=float(opt.fov_rad), max_range_m=float(opt.max_range_m),
                  min_range_m=float(opt.min_range_m))
    room = depths = None
    if opt.physics is not None:
        area = common_area(network, **limits) if isinstance(trajectory, str) else _box_of(states)
        room = room_box(opt.physics, np.array([p[:2] for p in poses.values()]), area)
        depths = person_depths(n_t, opt.physics, _stream(seed, _PEOPLE))
    setup = _Setup(levels=levels, options=opt, radar=radar, states=states,
                   bodies=_bodies(states, frame_period_s, opt, seed), limits=limits, seed=seed,
                   frames_c=_cube_frame_numbers(opt.cube_frames, n_f),
                   cube_memmap_dir=cube_memmap_dir, room=room, depths=depths)
    bar = None
    if "cube" in levels and progress:
        bar = tqdm(total=len(poses) * setup.frames_c.size, unit="frame", desc="raw ADC cubes")
    try:
        nodes = {name: _simulate_node(setup, i, name, pose, bar)
                 for i, (name, pose) in enumerate(poses.items())}
    finally:
        if bar is not None:
            bar.close()
    truth = Truth(frame=np.tile(np.arange(n_f), n_t), target_id=np.repeat(np.arange(n_t), n_f),
                  state=states.reshape(n_t * n_f, 4), node_poses=poses)
    # The clean model's centroids are point targets; the real model's are bodies.
    return Recording(frame_period_s=frame_period_s, nodes=nodes, truth=truth,
                     metadata=_metadata(network, trajectory, setup),
                     targets="points" if setup.options.physics is None else "people")


def _box_of(states: NDArray):
    """The walking area of given states (for the room's walls)."""
    xy = states[..., :2].reshape(-1, 2)
    return Area(x_min_m=float(xy[:, 0].min()), x_max_m=float(xy[:, 0].max()),
                y_min_m=float(xy[:, 1].min()), y_max_m=float(xy[:, 1].max()))
