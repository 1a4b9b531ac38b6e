"""A walk with instant turns: straight legs at constant speed between random
waypoints, the heading changing within no time at each waypoint (the velocity
jumps). The hardest case for a constant-velocity motion model: at every turn
the velocity changes by up to twice the speed between two frames, which the
model's white acceleration explains badly.

:func:`turning_walk` returns a callable ``states_at(times_s) -> (..., 4)``
(exact at any time, for clock-offset simulations, :mod:`.clocks`) and
:func:`turning_walk_states` its samples at the frames.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import ValidationError
from .._validation import as_float_array, check_count, check_finite

__all__ = ["turning_walk", "turning_walk_states"]


def _waypoints(center: NDArray, extent_m: float, n_legs: int, min_leg_m: float,
               rng: np.random.Generator) -> NDArray:
    """Random waypoints in the square ``center +- extent_m``, each leg at
    least ``min_leg_m`` long."""
    pts = [center + rng.uniform(-extent_m, extent_m, 2)]
    while len(pts) < n_legs + 1:
        p = center + rng.uniform(-extent_m, extent_m, 2)
        if np.linalg.norm(p - pts[-1]) >= min_leg_m:
            pts.append(p)
    return np.array(pts)


def turning_walk(center_m: ArrayLike, *, duration_s: float, speed_mps: float = 1.0,
                 extent_m: float = 1.5, min_leg_m: float = 1.0,
                 rng: np.random.Generator) -> Callable[[ArrayLike], NDArray]:
    """Legs at ``speed_mps`` between random waypoints in the square
    ``center_m +- extent_m`` (legs of at least ``min_leg_m``), instant turns
    at the waypoints; long enough for ``duration_s`` seconds from time 0
    (and as long again before it: negative times are on the path too).
    Returns ``states_at(times_s) -> (..., 4)`` global ``(x, y, vx, vy)``."""
    center = check_finite(as_float_array(center_m, "center_m"), "center_m")
    if center.shape != (2,):
        raise ValidationError(f"center_m must have shape (2,), got {center.shape}")
    for name, value in (("duration_s", duration_s), ("speed_mps", speed_mps),
                        ("extent_m", extent_m), ("min_leg_m", min_leg_m)):
        if not (np.isfinite(value) and value > 0):
            raise ValidationError(f"{name}={value!r} must be finite and > 0")
    if min_leg_m > 2.0 * extent_m:
        raise ValidationError(f"min_leg_m={min_leg_m!r} exceeds the square's side {2 * extent_m}")
    total_m = 2.0 * duration_s * speed_mps + 4.0 * extent_m
    n_legs = int(np.ceil(total_m / min_leg_m)) + 1
    pts = _waypoints(center, extent_m, n_legs, min_leg_m, rng)
    legs = np.diff(pts, axis=0)
    length = np.linalg.norm(legs, axis=1)
    direction = legs / length[:, None]
    start_s = np.concatenate([[0.0], np.cumsum(length)]) / speed_mps - duration_s

    def states_at(times_s: ArrayLike) -> NDArray:
        t = np.asarray(times_s, dtype=float)
        i = np.clip(np.searchsorted(start_s, t, side="right") - 1, 0, legs.shape[0] - 1)
        pos = pts[i] + direction[i] * (speed_mps * (t - start_s[i]))[..., None]
        return np.concatenate([pos, speed_mps * direction[i]], axis=-1)

    return states_at


def turning_walk_states(center_m: ArrayLike, *, n_frames: int, frame_period_s: float = 0.15,
                        rng: np.random.Generator, **options) -> NDArray:
    """:func:`turning_walk` sampled at frames ``0 .. n_frames-1``: (F, 4)."""
    check_count(n_frames, "n_frames")
    walk = turning_walk(center_m, duration_s=n_frames * frame_period_s, rng=rng, **options)
    return walk(np.arange(int(n_frames)) * frame_period_s)
