"""Target trajectories for the simulator (docs/SIMULATOR.md).

Each generator returns the global states ``(F, 4)`` = ``(x_m, y_m, vx_mps,
vy_mps)`` of a walking human's torso at frames ``0 .. F-1`` (time
``k * frame_period_s``), inside an :class:`~mmsnap_graph.sim.networks.Area`.
The motion is integrated on a fine time grid (``substeps`` per frame), so the
velocity is the derivative of the position, and sampled at the frames.

- ``"straight"``: walking back and forth along one straight line across the
  area (the paper's straight-line trajectory), cruising at ``speed_mps``,
  turning around with a bounded deceleration at each end.
- ``"random"``: a random walk: heading and speed are smooth random processes
  (speed kept in ``[min_speed_mps, max_speed_mps]``), steered back towards the
  area's centre near its edges, so the target stays inside the area.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import ValidationError
from .._validation import as_float_array, check_count, check_finite
from .networks import Area

__all__ = ["DEFAULT_N_FRAMES", "DEFAULT_FRAME_PERIOD_S", "straight_line", "random_walk",
           "make_trajectory", "TRAJECTORY_KINDS"]

DEFAULT_N_FRAMES = 600
DEFAULT_FRAME_PERIOD_S = 0.150
TRAJECTORY_KINDS = ("straight", "random")


def _check_common(n_frames: int, frame_period_s: float, substeps: int) -> None:
    check_count(n_frames, "n_frames")
    if not (np.isfinite(frame_period_s) and frame_period_s > 0):
        raise ValidationError(f"frame_period_s={frame_period_s!r} must be finite and > 0")
    check_count(substeps, "substeps")


def straight_line(area: Area, *, n_frames: int = DEFAULT_N_FRAMES,
                  frame_period_s: float = DEFAULT_FRAME_PERIOD_S,
                  speed_mps: float = 1.0, accel_mps2: float = 1.5,
                  start_m: ArrayLike | None = None, end_m: ArrayLike | None = None,
                  rng: np.random.Generator | None = None,
                  margin_m: float = 0.2, substeps: int = 10) -> NDArray:
    """Back and forth along the segment ``start_m -> end_m`` (global, (2,)).

    Without endpoints, the segment is the area's longer diagonal shrunk by
    ``margin_m`` (a random one of the two diagonals and a random starting end
    when ``rng`` is given). The walker cruises at ``speed_mps`` and reverses
    with deceleration ``accel_mps2`` so that it stops exactly at each end.
    Returns states ``(n_frames, 4)``.
    """
    _check_common(n_frames, frame_period_s, substeps)
    if not (0 < speed_mps <= 3.0):
        raise ValidationError(f"speed_mps={speed_mps!r} must be in (0, 3] for a walking human")
    if not accel_mps2 > 0:
        raise ValidationError(f"accel_mps2={accel_mps2!r} must be > 0")
    if start_m is None or end_m is None:
        lo = np.array([area.x_min_m, area.y_min_m]) + margin_m
        hi = np.array([area.x_max_m, area.y_max_m]) - margin_m
        diag = [(lo, hi), (np.array([lo[0], hi[1]]), np.array([hi[0], lo[1]]))]
        pick = 0 if rng is None else int(rng.integers(2))
        a, b = diag[pick]
        if rng is not None and rng.integers(2):
            a, b = b, a
    else:
        a = check_finite(as_float_array(start_m, "start_m"), "start_m")
        b = check_finite(as_float_array(end_m, "end_m"), "end_m")
        if a.shape != (2,) or b.shape != (2,):
            raise ValidationError(f"start_m and end_m must have shape (2,), got {a.shape}, {b.shape}")
    length = float(np.linalg.norm(b - a))
    if length < 1e-6:
        raise ValidationError(f"start_m and end_m must differ, got {a} and {b}")
    direction = (b - a) / length
    dt = frame_period_s / substeps
    n_fine = (n_frames - 1) * substeps + 1
    s = np.empty(n_fine)
    v = np.empty(n_fine)
    pos, vel, sign = 0.0, 0.0, 1.0
    for k in range(n_fine):
        s[k], v[k] = pos, vel
        # Target velocity: cruise toward the current end; brake so as to stop at it.
        remaining = length - pos if sign > 0 else pos
        v_brake = np.sqrt(max(2.0 * accel_mps2 * max(remaining, 0.0), 0.0))
        v_cmd = sign * min(speed_mps, v_brake)
        if remaining <= 1e-9 or (abs(vel) < 1e-9 and v_brake < 1e-9):
            sign = -sign
            v_cmd = sign * min(speed_mps, accel_mps2 * dt)
        dv = np.clip(v_cmd - vel, -accel_mps2 * dt, accel_mps2 * dt)
        new_vel = vel + dv
        pos = float(np.clip(pos + 0.5 * (vel + new_vel) * dt, 0.0, length))
        vel = new_vel
        if (sign > 0 and pos >= length - 1e-9) or (sign < 0 and pos <= 1e-9):
            vel = 0.0
    s = s[::substeps]
    v = v[::substeps]
    xy = a[None, :] + s[:, None] * direction[None, :]
    vxy = v[:, None] * direction[None, :]
    return np.concatenate([xy, vxy], axis=1)


def random_walk(area: Area, *, n_frames: int = DEFAULT_N_FRAMES,
                frame_period_s: float = DEFAULT_FRAME_PERIOD_S,
                rng: np.random.Generator | None = None, seed: int | None = None,
                mean_speed_mps: float = 1.0, min_speed_mps: float = 0.5,
                max_speed_mps: float = 1.5, turn_rate_std_rad_per_s: float = 0.6,
                turn_tau_s: float = 1.0,
                speed_tau_s: float = 3.0, margin_m: float = 0.3,
                substeps: int = 10) -> NDArray:
    """A smooth random walk inside ``area`` (shrunk by ``margin_m``).

    Heading: its rate of turn is an Ornstein-Uhlenbeck process (standard
    deviation ``turn_rate_std_rad_per_s``, time constant ``turn_tau_s``), so
    the path is smooth; a steering term turns the walker toward the area
    centre (at up to 3 rad/s) when the point one second ahead leaves the inner
    box. Speed: Ornstein-Uhlenbeck around
    ``mean_speed_mps`` with time constant ``speed_tau_s``, clipped to
    ``[min_speed_mps, max_speed_mps]``. Seeded by ``rng`` or ``seed``.
    Returns states ``(n_frames, 4)``.
    """
    _check_common(n_frames, frame_period_s, substeps)
    if not (0 < min_speed_mps <= mean_speed_mps <= max_speed_mps <= 3.0):
        raise ValidationError(
            f"speeds must satisfy 0 < min_speed_mps={min_speed_mps!r} <= mean_speed_mps="
            f"{mean_speed_mps!r} <= max_speed_mps={max_speed_mps!r} <= 3")
    if np.any(area.size_m <= 2 * margin_m + 0.2):
        raise ValidationError(f"area {area} is too small for margin_m={margin_m}")
    if rng is None:
        rng = np.random.default_rng(seed)
    dt = frame_period_s / substeps
    n_fine = (n_frames - 1) * substeps + 1
    inner = Area(x_min_m=area.x_min_m + margin_m, x_max_m=area.x_max_m - margin_m,
                 y_min_m=area.y_min_m + margin_m, y_max_m=area.y_max_m - margin_m)
    center = area.center_m
    lo = np.array([area.x_min_m, area.y_min_m]) + 0.05
    hi = np.array([area.x_max_m, area.y_max_m]) - 0.05
    pos = inner.center_m + (rng.uniform(-0.5, 0.5, 2) * inner.size_m)
    heading = rng.uniform(-np.pi, np.pi)
    speed = mean_speed_mps
    turn_rate = 0.0
    speed_std = 0.25 * (max_speed_mps - min_speed_mps)
    max_turn_rate = 3.0  # rad/s while steering back: a brisk but human turn
    out = np.empty((n_fine, 4))
    for k in range(n_fine):
        vel = speed * np.array([np.cos(heading), np.sin(heading)])
        out[k, :2] = pos
        out[k, 2:] = vel
        ahead = pos + vel * 1.0
        if not inner.contains(ahead):
            to_c = center - pos
            want = np.arctan2(to_c[1], to_c[0])
            err = (want - heading + np.pi) % (2 * np.pi) - np.pi
            heading += np.clip(err, -max_turn_rate * dt, max_turn_rate * dt)
        turn_rate += (-turn_rate / turn_tau_s * dt + turn_rate_std_rad_per_s
                      * np.sqrt(2 * dt / turn_tau_s) * rng.standard_normal())
        heading += turn_rate * dt
        speed += ((mean_speed_mps - speed) / speed_tau_s * dt
                  + speed_std * np.sqrt(2 * dt / speed_tau_s) * rng.standard_normal())
        speed = float(np.clip(speed, min_speed_mps, max_speed_mps))
        new_vel = speed * np.array([np.cos(heading), np.sin(heading)])
        pos = np.clip(pos + 0.5 * (vel + new_vel) * dt, lo, hi)
    return out[::substeps].copy()


def make_trajectory(kind: Literal["straight", "random"], area: Area, *,
                    n_frames: int = DEFAULT_N_FRAMES,
                    frame_period_s: float = DEFAULT_FRAME_PERIOD_S,
                    rng: np.random.Generator | None = None, seed: int | None = None,
                    **options) -> NDArray:
    """Dispatch on ``kind`` (``"straight"`` or ``"random"``); states ``(F, 4)``."""
    if rng is None:
        rng = np.random.default_rng(seed)
    if kind == "straight":
        return straight_line(area, n_frames=n_frames, frame_period_s=frame_period_s,
                             rng=rng, **options)
    if kind == "random":
        return random_walk(area, n_frames=n_frames, frame_period_s=frame_period_s,
                           rng=rng, **options)
    raise ValidationError(f"trajectory kind={kind!r} must be one of {TRAJECTORY_KINDS}")
