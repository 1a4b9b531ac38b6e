"""Calibration scenes with node clock offsets: each node measures
the target at its own frame times, late or early against the reference by a
fraction of a frame or more.

Convention (docs/FORMAT.md, ``/calibration/time_offset_s``): node time +
offset = reference time. A node with offset ``tau`` stamps frame ``k`` at its
own time ``k T``, which is the reference time ``k T + tau``: its frame-``k``
detection is of the target ``tau`` seconds after the reference's frame ``k``.
The truth is sampled exactly along the trajectory at those times (a fine grid
and cubic Hermite interpolation of positions and velocities, or the exact
path of :func:`~mmsnap_graph.sim.turns.turning_walk`).
"""

from __future__ import annotations

import dataclasses
from typing import Callable, Literal, Mapping

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.interpolate import CubicHermiteSpline

from factors.models import detection_to_local, global_to_local, measurement_model, wrap_angle

from ..data.noise import MeasurementNoise
from ..data.recording import Detections, NodeData, Recording, Truth
from .._validation import check_count
from ..errors import GeometryError, ValidationError
from .scenes import SCENE_NOISE, SyntheticScene, target_trajectory
from .networks import Area
from .trajectories import RandomWalkOptions, random_walk
from .turns import turning_walk

__all__ = ["trajectory_function", "timed_scene", "scene_recording", "offset_recording"]


def trajectory_function(kind: Literal["random", "straight", "walk", "turns"], center_m: ArrayLike,
                        *,
                        duration_s: float, frame_period_s: float = 0.15, extent_m: float = 1.5,
                        rng: np.random.Generator, substeps: int = 20,
                        pad_s: float = 2.0) -> Callable[[ArrayLike], NDArray]:
    """``states_at(times_s) -> (..., 4)`` for times in ``[-pad_s, duration_s
    + pad_s]``: ``"random"`` and ``"straight"`` are
    :func:`~mmsnap_graph.sim.scenes.target_trajectory` on a grid of
    ``frame_period_s / substeps`` interpolated by cubic Hermite splines
    (positions with their velocities; the velocity is the spline's
    derivative); ``"walk"`` is the simulator's random walk
    (:func:`~mmsnap_graph.sim.trajectories.random_walk`, about 1 m/s, in the
    square ``center_m +- extent_m``) on the same grid; ``"turns"`` is
    :func:`~mmsnap_graph.sim.turns.turning_walk` (exact)."""
    center = np.asarray(center_m, dtype=float)
    if kind == "turns":
        return turning_walk(center, duration_s=duration_s + pad_s, extent_m=extent_m, rng=rng)
    if kind not in ("random", "straight", "walk"):
        raise ValidationError(f"kind={kind!r} must be 'random', 'straight', 'walk' or 'turns'")
    dt = frame_period_s / substeps
    n = int(np.ceil((duration_s + 2 * pad_s) / dt)) + 2
    if kind == "walk":
        area = Area(x_min_m=center[0] - extent_m, x_max_m=center[0] + extent_m,
                    y_min_m=center[1] - extent_m, y_max_m=center[1] + extent_m)
        fine = random_walk(area, n_frames=n, frame_period_s=dt, rng=rng,
                           options=RandomWalkOptions(substeps=1))
    else:
        fine = target_trajectory(n, center, frame_period_s=dt, kind=kind, extent_m=extent_m,
                                 rng=rng)
    t = np.arange(n) * dt - pad_s
    spline = CubicHermiteSpline(t, fine[:, :2], fine[:, 2:], axis=0)
    deriv = spline.derivative()

    def states_at(times_s: ArrayLike) -> NDArray:
        ts = np.asarray(times_s, dtype=float)
        if np.any(ts < t[0]) or np.any(ts > t[-1]):
            raise ValidationError(f"times outside [{t[0]:.3f}, {t[-1]:.3f}] s")
        return np.concatenate([spline(ts), deriv(ts)], axis=-1)

    return states_at


def _check_offsets(poses, time_offsets_s) -> dict[str, float]:
    out = {}
    for name in poses:
        tau = float(time_offsets_s.get(name, 0.0))
        if not np.isfinite(tau):
            raise ValidationError(f"time_offsets_s[{name!r}]={tau!r} must be finite")
        out[name] = tau
    unknown = set(time_offsets_s) - set(poses)
    if unknown:
        raise ValidationError(f"time_offsets_s names unknown nodes {sorted(unknown)}")
    return out


def timed_scene(poses: Mapping[str, ArrayLike], *, time_offsets_s: Mapping[str, float],
                n_frames: int = 600, frame_period_s: float = 0.15,
                kind: Literal["random", "straight", "walk", "turns"] = "random",
                noise: MeasurementNoise = SCENE_NOISE, center_m: ArrayLike | None = None,
                extent_m: float = 1.5, min_range_m: float = 1.0,
                rng: np.random.Generator) -> SyntheticScene:
    """One target seen by every node at every frame, each node's frame ``k``
    taken at reference time ``k T + time_offsets_s[node]`` (module doc).

    ``truth`` is the state at the reference frame times ``k T``; ``measurements``
    are the model at each node's own sampling times plus Gaussian ``noise``.
    Offsets may exceed a frame (|tau| up to 2 s). A target behind a node or
    closer than ``min_range_m`` raises :class:`GeometryError`.
    """
    if not isinstance(noise, MeasurementNoise):
        raise ValidationError(f"noise must be a MeasurementNoise, got {noise!r}")
    poses = {k: np.asarray(v, dtype=float) for k, v in poses.items()}
    taus = _check_offsets(poses, time_offsets_s)
    if max(abs(v) for v in taus.values()) > 2.0:
        raise ValidationError("time offsets beyond 2 s are not simulated")
    if center_m is None:
        center_m = np.mean([p[:2] for p in poses.values()], axis=0)
    t = np.arange(int(n_frames)) * frame_period_s
    walk = trajectory_function(kind, center_m, duration_s=float(t[-1]) + frame_period_s,
                               frame_period_s=frame_period_s, extent_m=extent_m, rng=rng)
    truth = walk(t)
    meas, local, ghost = {}, {}, {}
    for name, pose in poses.items():
        states = walk(t + taus[name])
        if np.any(global_to_local(states[:, :2], pose)[:, 1] <= 0):
            raise GeometryError(f"the trajectory leaves node {name}'s half plane")
        h = measurement_model(states, pose)[0]
        if np.any(h[:, 0] < min_range_m):
            raise GeometryError(f"the trajectory comes within {h[:, 0].min():.2f} m of node {name}")
        z = h + rng.standard_normal(h.shape) * noise.sigmas
        z[:, 1] = wrap_angle(z[:, 1])
        meas[name] = z
        local[name] = detection_to_local(z[:, 0], z[:, 1])
        ghost[name] = np.zeros(t.size, dtype=bool)
    return SyntheticScene(poses=poses, frame=np.arange(t.size), truth=truth, measurements=meas,
                          local_points_m=local, ghost=ghost, noise=noise,
                          frame_period_s=frame_period_s)


def scene_recording(scene: SyntheticScene) -> Recording:
    """A :class:`Recording` of a scene's centroids (one per node per frame,
    on each node's own frame clock), with the truth at the reference frame
    times and the noise in the metadata (``centroid_*_std_*``, as the
    simulator writes it), for :func:`~mmsnap_graph.calibration.calibrate_recording`
    and :func:`~mmsnap_graph.fusion.recording.sequence.fuse_recording`."""
    nodes = {}
    for name, z in scene.measurements.items():
        det = Detections(frame=scene.frame, range_m=np.abs(z[:, 0]), omega_rad=z[:, 1],
                         doppler_mps=z[:, 2], target_id=np.zeros(scene.frame.size, dtype=int))
        nodes[name] = NodeData(name=name, centroids=det)
    truth = Truth(frame=scene.frame, target_id=np.zeros(scene.frame.size, dtype=int),
                  state=scene.truth, node_poses=dict(scene.poses))
    metadata = {"generator": "mmsnap_graph.sim.clocks.timed_scene",
                "centroid_range_std_m": scene.noise.range_m,
                "centroid_omega_std_rad": scene.noise.omega_rad,
                "centroid_doppler_std_mps": scene.noise.doppler_mps}
    return Recording(frame_period_s=scene.frame_period_s, nodes=nodes, truth=truth,
                     metadata=metadata, targets="points")


def _picked(frame: NDArray, shift: int, oversample: int, n_frames: int) -> tuple[NDArray, NDArray]:
    """Rows of the fine frames ``shift + k * oversample`` (k < n_frames) and their ``k``."""
    rel = np.asarray(frame) - shift
    rows = np.flatnonzero((rel >= 0) & (rel % oversample == 0) & (rel // oversample < n_frames))
    return rows, rel[rows] // oversample


def _node_frames(det: Detections, shift: int, oversample: int, n_frames: int) -> Detections:
    rows, k = _picked(det.frame, shift, oversample, n_frames)
    return Detections(frame=k, range_m=det.range_m[rows], omega_rad=det.omega_rad[rows],
                      doppler_mps=det.doppler_mps[rows],
                      snr_db=None if det.snr_db is None else det.snr_db[rows],
                      target_id=None if det.target_id is None else det.target_id[rows])


def offset_recording(network, trajectory: str = "straight", options=None, *,
                     time_offsets_s: Mapping[str, float], n_frames: int = 600, seed: int = 0,
                     oversample: int = 10) -> Recording:
    """The simulator's centroids (:func:`~mmsnap_graph.sim.simulate_recording`,
    any model: the real physics by default, :data:`~mmsnap_graph.sim.CLEAN`)
    with node clock offsets: the scene is simulated at ``oversample`` times
    the frame rate, and each node keeps every ``oversample``-th fine frame
    from its own start, ``round(tau / (T / oversample))`` fine frames after
    the reference's (so the offsets are exact to ``T / (2 oversample)``).

    Convention as :func:`timed_scene`: node frame ``k`` is taken at the
    reference time ``k T + tau``. The truth is at the reference frames.
    ``n_frames`` frames of period ``T`` (``options.frame_period_s``, else the
    radar's); offsets up to 2 s.
    """
    from .options import SimulationOptions
    from .simulator import simulate_recording

    opt = SimulationOptions() if options is None else options
    if not isinstance(opt, SimulationOptions):
        raise ValidationError(f"options must be a SimulationOptions, got {type(opt).__name__}")
    check_count(n_frames, "n_frames")
    check_count(oversample, "oversample")
    period = opt.radar.frame_period_s if opt.frame_period_s is None else opt.frame_period_s
    fine = period / oversample
    pad = int(np.ceil(2.0 / fine))
    shifts = {}
    for name, tau in time_offsets_s.items():
        tau = float(tau)
        if not (np.isfinite(tau) and abs(tau) <= 2.0):
            raise ValidationError(f"time_offsets_s[{name!r}]={tau!r} must be finite seconds "
                                  "within +-2 s (milliseconds given?)")
        shifts[name] = pad + int(round(tau / fine))
    rec = simulate_recording(network, trajectory,
                             dataclasses.replace(opt, frame_period_s=fine),
                             levels=("centroids",), n_frames=(n_frames - 1) * oversample + 2 * pad + 1,
                             seed=seed)
    unknown = set(shifts) - set(rec.node_names)
    if unknown:
        raise ValidationError(f"time_offsets_s names unknown nodes {sorted(unknown)}")
    nodes = {name: dataclasses.replace(node, centroids=_node_frames(
        node.centroids, shifts.get(name, pad), oversample, n_frames))
        for name, node in rec.nodes.items()}
    rows, k = _picked(rec.truth.frame, pad, oversample, n_frames)
    truth = Truth(frame=k, target_id=rec.truth.target_id[rows], state=rec.truth.state[rows],
                  node_poses=rec.truth.node_poses)
    metadata = {**rec.metadata, "generator": "mmsnap_graph.sim.clocks.offset_recording",
                "time_offsets_s": np.array([(shifts.get(n, pad) - pad) * fine
                                            for n in rec.node_names])}
    return Recording(frame_period_s=period, nodes=nodes, truth=truth, metadata=metadata,
                     targets=rec.targets)
