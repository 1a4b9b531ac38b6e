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
  (:class:`RandomWalkOptions`; speed kept in ``[min_speed_mps, max_speed_mps]``), steered back towards the
  area's centre near its edges, so the target stays inside the area.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import ValidationError
from .._validation import as_float_array, check_count, check_finite
from .networks import Area

__all__ = ["DEFAULT_N_FRAMES", "DEFAULT_FRAME_PERIOD_S", "straight_line", "random_walk",
           "RandomWalkOptions",
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


@dataclass(frozen=True, kw_only=True)
class RandomWalkOptions:
    """How the ``"random"`` walker moves (frozen; validated once).

    Heading: its rate of turn is an Ornstein-Uhlenbeck process (standard
    deviation ``turn_rate_std_rad_per_s``, time constant ``turn_tau_s``).
    Speed: Ornstein-Uhlenbeck around ``mean_speed_mps`` with time constant
    ``speed_tau_s``, clipped to ``[min_speed_mps, max_speed_mps]``. The walker
    keeps ``margin_m`` from the area's edges; the motion is integrated on
    ``substeps`` fine steps per frame.
    """

    mean_speed_mps: float = 1.0
    min_speed_mps: float = 0.5
    max_speed_mps: float = 1.5
    turn_rate_std_rad_per_s: float = 0.6
    turn_tau_s: float = 1.0
    speed_tau_s: float = 3.0
    margin_m: float = 0.3
    substeps: int = 10

    def __post_init__(self) -> None:
        if not (0 < self.min_speed_mps <= self.mean_speed_mps <= self.max_speed_mps <= 3.0):
            raise ValidationError(
                "RandomWalkOptions speeds must satisfy 0 < min_speed_mps="
                f"{self.min_speed_mps!r} <= mean_speed_mps={self.mean_speed_mps!r} <= "
                f"max_speed_mps={self.max_speed_mps!r} <= 3 (m/s)")
        for name in ("turn_tau_s", "speed_tau_s"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValidationError(f"RandomWalkOptions.{name}={v!r} must be finite and > 0 "
                                      "(seconds)")
        if not (np.isfinite(self.turn_rate_std_rad_per_s) and self.turn_rate_std_rad_per_s >= 0):
            raise ValidationError("RandomWalkOptions.turn_rate_std_rad_per_s="
                                  f"{self.turn_rate_std_rad_per_s!r} must be finite and >= 0")
        if not (np.isfinite(self.margin_m) and self.margin_m >= 0):
            raise ValidationError(f"RandomWalkOptions.margin_m={self.margin_m!r} must be finite "
                                  "and >= 0 (metres)")
        check_count(self.substeps, "RandomWalkOptions.substeps")


def random_walk(area: Area, *, n_frames: int = DEFAULT_N_FRAMES,
                frame_period_s: float = DEFAULT_FRAME_PERIOD_S,
                rng: np.random.Generator | None = None, seed: int | None = None,
                options: RandomWalkOptions | None = None) -> NDArray:
    """A smooth random walk inside ``area`` (shrunk by ``options.margin_m``).

    The heading's rate of turn and the speed are Ornstein-Uhlenbeck processes
    (:class:`RandomWalkOptions`, defaults if ``options`` is None), so the path
    is smooth; a steering term turns the walker toward the area centre (at up
    to 3 rad/s) when the point one second ahead leaves the inner box. Seeded
    by ``rng`` or ``seed``. Returns states ``(n_frames, 4)``.
    """
    opt = RandomWalkOptions() if options is None else options
    if not isinstance(opt, RandomWalkOptions):
        raise ValidationError(f"options must be a RandomWalkOptions, got {type(opt).__name__}")
    substeps, margin_m = opt.substeps, opt.margin_m
    mean_speed_mps, min_speed_mps, max_speed_mps = (opt.mean_speed_mps, opt.min_speed_mps,
                                                    opt.max_speed_mps)
    turn_tau_s, speed_tau_s = opt.turn_tau_s, opt.speed_tau_s
    turn_rate_std_rad_per_s = opt.turn_rate_std_rad_per_s
    _check_common(n_frames, frame_period_s, substeps)
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
                    walk: RandomWalkOptions | None = None, **straight_options) -> NDArray:
    """Dispatch on ``kind`` (``"straight"`` or ``"random"``); states ``(F, 4)``.

    ``walk`` tunes the ``"random"`` kind; ``straight_options`` are the
    keywords of :func:`straight_line`.
    """
    if rng is None:
        rng = np.random.default_rng(seed)
    if kind == "straight":
        if walk is not None:
            raise ValidationError("RandomWalkOptions tune trajectory kind 'random', not "
                                  "'straight'")
        return straight_line(area, n_frames=n_frames, frame_period_s=frame_period_s,
                             rng=rng, **straight_options)
    if kind == "random":
        if straight_options:
            raise ValidationError(f"trajectory kind 'random' takes a RandomWalkOptions, not "
                                  f"keywords {sorted(straight_options)}")
        return random_walk(area, n_frames=n_frames, frame_period_s=frame_period_s,
                           rng=rng, options=walk)
    raise ValidationError(f"trajectory kind={kind!r} must be one of {TRAJECTORY_KINDS}")
