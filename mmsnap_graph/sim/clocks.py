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

from typing import Callable, Literal, Mapping

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.interpolate import CubicHermiteSpline

from factors.models import detection_to_local, global_to_local, measurement_model, wrap_angle

from ..data.noise import MeasurementNoise
from ..data.recording import Detections, NodeData, Recording, Truth
from ..errors import GeometryError, ValidationError
from .scenes import SCENE_NOISE, SyntheticScene, target_trajectory
from .networks import Area
from .trajectories import random_walk
from .turns import turning_walk

__all__ = ["trajectory_function", "timed_scene", "scene_recording"]


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
        fine = random_walk(area, n_frames=n, frame_period_s=dt, rng=rng, substeps=1)
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
                     metadata=metadata)
