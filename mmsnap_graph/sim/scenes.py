"""Small synthetic calibration scenes for the calibration tests and benchmark.

Numpy only, built on the shared models of :mod:`factors.models`: a smooth
target trajectory in the global frame, each node's noise-free measurements
from ``measurement_model``, additive Gaussian noise with the radar's
anisotropy (centimetres in range, a large spatial-frequency noise, so
decimetres across range), optional ghost frames. This is not the project
simulator (:mod:`mmsnap_graph.sim`, which adds DSP, bodies and clutter); it
exists so that calibration can be tested against known poses on its own.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, Mapping

import numpy as np
from numpy.typing import NDArray

from factors.models import detection_to_local, global_to_local, measurement_model, wrap_angle

from .networks import COMMON_AREAS, CONFIGURATIONS

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


@dataclass(frozen=True, kw_only=True, slots=True)
class SyntheticScene:
    """One target seen by several nodes at frames ``0..K-1``.

    poses : name -> (3,) true pose. frame : (K,) int. truth : (K, 4) global.
    measurements : name -> (K, 3) noisy ``(range_m, omega_rad, doppler_mps)``.
    local_points_m : name -> (K, 2) the detections in the node's local frame.
    ghost : name -> (K,) bool, frames whose detection is a ghost.
    sigmas : (3,) the measurement noise used.
    """

    poses: Mapping[str, NDArray]
    frame: NDArray
    truth: NDArray
    measurements: Mapping[str, NDArray]
    local_points_m: Mapping[str, NDArray]
    ghost: Mapping[str, NDArray]
    sigmas: NDArray
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
        raise ValueError(f"kind={kind!r} must be 'random', 'straight' or 'standing'")
    return np.concatenate([pos + c, vel], axis=1)


def synthetic_scene(
    poses: Mapping[str, NDArray], *, n_frames: int = 600, center_m: NDArray | None = None,
    sigmas: NDArray = (0.035, 0.2, 0.18), frame_period_s: float = 0.15,
    kind: Literal["random", "straight", "standing"] = "random", extent_m: float = 1.5,
    ghost_fraction: float = 0.0, min_range_m: float = 1.0, rng: np.random.Generator,
) -> SyntheticScene:
    """Noisy measurements of one target by each node (module doc).

    sigmas : (3,) noise of ``(range_m, omega_rad, doppler_mps)``.
    ghost_fraction : fraction of frames, drawn independently per node, whose
        detection is replaced by a ghost: uniform range 1-10 m, uniform
        ``omega`` in ``(-pi/2, pi/2)``, uniform Doppler in +-2 m/s.
    min_range_m : a trajectory closer than this to a node raises ValueError.
    """
    poses = {k: np.asarray(v, dtype=float) for k, v in poses.items()}
    if center_m is None:
        center_m = np.mean([p[:2] for p in poses.values()], axis=0)
    sig = np.asarray(sigmas, dtype=float)
    truth = target_trajectory(n_frames, center_m, frame_period_s=frame_period_s, kind=kind,
                              extent_m=extent_m, rng=rng)
    meas, local, ghost = {}, {}, {}
    for name, pose in poses.items():
        h, _ = measurement_model(truth, pose)
        z = h + rng.normal(size=h.shape) * sig
        z[:, 1] = np.clip(wrap_angle(z[:, 1]), -np.pi, np.pi)
        z[:, 0] = np.abs(z[:, 0])
        g = rng.random(n_frames) < ghost_fraction
        n_g = int(g.sum())
        z[g, 0] = rng.uniform(1.0, 10.0, n_g)
        z[g, 1] = rng.uniform(-np.pi / 2, np.pi / 2, n_g)
        z[g, 2] = rng.uniform(-2.0, 2.0, n_g)
        meas[name] = z
        local[name] = detection_to_local(z[:, 0], z[:, 1])
        ghost[name] = g
        # Every target must be in front of every node, or the scene is wrong.
        if np.any(global_to_local(truth[:, :2], pose)[:, 1] <= 0):
            raise ValueError(f"the trajectory leaves node {name}'s half plane")
        if np.any(h[:, 0] < min_range_m):
            raise ValueError(f"the trajectory comes within {h[:, 0].min():.2f} m of node {name}")
    return SyntheticScene(poses=poses, frame=np.arange(n_frames), truth=truth,
                          measurements=meas, local_points_m=local, ghost=ghost, sigmas=sig,
                          frame_period_s=frame_period_s)
