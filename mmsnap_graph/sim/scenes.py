"""Small calibration scenes (one target seen by several nodes at every frame)
for the calibration tests and benchmark.

A scene is a short simulation made with the simulator's own parts: a smooth
target trajectory in the global frame (:func:`target_trajectory`), each
node's centroid measurements from :func:`~mmsnap_graph.sim.simulate_recording`
(level ``"centroids"``: :func:`factors.models.measurement_model` plus
Gaussian noise of the given :class:`~mmsnap_graph.data.noise.MeasurementNoise`,
every frame kept), and optional ghost frames whose detection is replaced by
a random one. The whole scene is drawn from the ``rng`` it is given.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, Mapping

import numpy as np
from numpy.typing import NDArray

from factors.models import detection_to_local, global_to_local, measurement_model

from ..data.noise import MeasurementNoise
from ..errors import GeometryError, ValidationError
from .networks import COMMON_AREAS, CONFIGURATIONS
from .options import SimulationOptions
from .simulator import simulate_recording

__all__ = ["PAPER_CONFIGURATIONS", "COMMON_AREA_CENTERS", "SyntheticScene",
           "target_trajectory", "synthetic_scene"]

#: The paper's configurations (S1 at the origin), from :mod:`mmsnap_graph.sim.networks`.
PAPER_CONFIGURATIONS: dict[str, dict[str, NDArray]] = {
    name: {node: np.array(pose) for node, pose in poses.items()}
    for name, poses in CONFIGURATIONS.items()
}
#: Centre of each configuration's common walking area (global, m).
COMMON_AREA_CENTERS: dict[str, NDArray] = {
    name: np.array([(a.x_min_m + a.x_max_m) / 2.0, (a.y_min_m + a.y_max_m) / 2.0])
    for name, a in COMMON_AREAS.items()
}
#: The scenes' default noise: the paper's range and Doppler sigmas, a
#: moderate spatial-frequency sigma (decimetres across range).
SCENE_NOISE = MeasurementNoise(range_m=0.035, omega_rad=0.2, doppler_mps=0.18)


@dataclass(frozen=True, kw_only=True, slots=True)
class SyntheticScene:
    """One target seen by several nodes at frames ``0..K-1``.

    poses : name -> (3,) true pose. frame : (K,) int. truth : (K, 4) global.
    measurements : name -> (K, 3) noisy ``(range_m, omega_rad, doppler_mps)``.
    local_points_m : name -> (K, 2) the detections in the node's local frame.
    ghost : name -> (K,) bool, frames whose detection is a ghost.
    noise : the measurement noise used.
    """

    poses: Mapping[str, NDArray]
    frame: NDArray
    truth: NDArray
    measurements: Mapping[str, NDArray]
    local_points_m: Mapping[str, NDArray]
    ghost: Mapping[str, NDArray]
    noise: MeasurementNoise
    frame_period_s: float


def target_trajectory(
    n_frames: int, center_m: NDArray, *, frame_period_s: float = 0.15,
    kind: Literal["random", "straight", "standing"] = "random",
    extent_m: float = 1.5, rng: np.random.Generator,
) -> NDArray:
    """A smooth walking trajectory, (K, 4) ``(x, y, vx, vy)`` global.

    ``random``: a sum of three sinusoids per axis with random phases and
    periods of 10-40 s (walking speeds ~ 0.3-1 m/s); ``straight``: back and
    forth along a random line through the centre; ``standing``: still.
    (These are not the simulator's walks of :mod:`mmsnap_graph.sim.trajectories`:
    the calibration tests' tolerances were set on them, and a standing
    target is the unobservable case they need.)
    """
    t = np.arange(n_frames) * frame_period_s
    c = np.asarray(center_m, dtype=float)
    pos = np.zeros((n_frames, 2))
    vel = np.zeros((n_frames, 2))
    if kind == "random":
        for axis in range(2):
            for _ in range(3):
                period = rng.uniform(10.0, 40.0)
                w = 2 * np.pi / period
                ph = rng.uniform(0, 2 * np.pi)
                amp = extent_m / 2.0
                pos[:, axis] += amp * np.sin(w * t + ph)
                vel[:, axis] += amp * w * np.cos(w * t + ph)
    elif kind == "straight":
        ang = rng.uniform(0, np.pi)
        d = np.array([np.cos(ang), np.sin(ang)])
        w = 2 * np.pi / 20.0
        s = 1.5 * extent_m * np.sin(w * t)
        sd = 1.5 * extent_m * w * np.cos(w * t)
        pos = s[:, None] * d
        vel = sd[:, None] * d
    elif kind != "standing":
        raise ValidationError(f"kind={kind!r} must be 'random', 'straight' or 'standing'")
    return np.concatenate([pos + c, vel], axis=1)


def _check_geometry(truth: NDArray, poses: Mapping[str, NDArray], min_range_m: float) -> None:
    """Every target must be in front of every node, or the scene is wrong."""
    for name, pose in poses.items():
        if np.any(global_to_local(truth[:, :2], pose)[:, 1] <= 0):
            raise GeometryError(f"the trajectory leaves node {name}'s half plane")
        r = measurement_model(truth, pose)[0][:, 0]
        if np.any(r < min_range_m):
            raise GeometryError(f"the trajectory comes within {r.min():.2f} m of node {name}")


def _add_ghosts(z: NDArray, ghost_fraction: float, rng: np.random.Generator) -> NDArray:
    """Replace a random ``ghost_fraction`` of the rows by ghosts; the mask."""
    g = rng.random(z.shape[0]) < ghost_fraction
    n_g = int(g.sum())
    z[g, 0] = rng.uniform(1.0, 10.0, n_g)
    z[g, 1] = rng.uniform(-np.pi / 2, np.pi / 2, n_g)
    z[g, 2] = rng.uniform(-2.0, 2.0, n_g)
    return g


def synthetic_scene(
    poses: Mapping[str, NDArray], *, n_frames: int = 600, center_m: NDArray | None = None,
    noise: MeasurementNoise = SCENE_NOISE, frame_period_s: float = 0.15,
    kind: Literal["random", "straight", "standing"] = "random", extent_m: float = 1.5,
    ghost_fraction: float = 0.0, min_range_m: float = 1.0, rng: np.random.Generator,
) -> SyntheticScene:
    """Noisy measurements of one target by each node at every frame (module doc).

    noise : the measurements' noise (default :data:`SCENE_NOISE`).
    ghost_fraction : fraction of frames, drawn independently per node, whose
        detection is replaced by a ghost: uniform range 1-10 m, uniform
        ``omega`` in ``(-pi/2, pi/2)``, uniform Doppler in +-2 m/s.
    min_range_m : a trajectory closer than this to a node, or behind one,
        raises :class:`GeometryError`.
    """
    if not isinstance(noise, MeasurementNoise):
        raise ValidationError(f"noise must be a MeasurementNoise, got {noise!r}")
    poses = {k: np.asarray(v, dtype=float) for k, v in poses.items()}
    if center_m is None:
        center_m = np.mean([p[:2] for p in poses.values()], axis=0)
    truth = target_trajectory(n_frames, center_m, frame_period_s=frame_period_s, kind=kind,
                              extent_m=extent_m, rng=rng)
    _check_geometry(truth, poses, min_range_m)
    # Every frame in view (the half plane was checked): the widest limits.
    # The clean model: these scenes test estimators against their own model.
    rec = simulate_recording(
        poses, truth, SimulationOptions(physics=None, frame_period_s=frame_period_s,
                                        fov_rad=np.pi / 2, min_range_m=0.0, max_range_m=np.inf,
                                        centroid_noise=noise),
        levels=("centroids",), seed=int(rng.integers(2**63)))
    meas, local, ghost = {}, {}, {}
    for name in poses:
        z = rec.nodes[name].centroids.measurements.copy()
        if z.shape[0] != n_frames:
            raise GeometryError(f"node {name} sees the target in {z.shape[0]} of {n_frames} frames")
        ghost[name] = _add_ghosts(z, ghost_fraction, rng)
        meas[name] = z
        local[name] = detection_to_local(z[:, 0], z[:, 1])
    return SyntheticScene(poses=poses, frame=np.arange(n_frames), truth=truth,
                          measurements=meas, local_points_m=local, ghost=ghost, noise=noise,
                          frame_period_s=frame_period_s)
