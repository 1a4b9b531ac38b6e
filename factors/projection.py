"""3D points in a tilted, raised radar's frame -> the 2D measurement plane.

Pure numpy, vectorised over leading axes (docs/TI.md derives every formula;
docs/CONVENTIONS.md, "3D point clouds", states them).

Frames:

- **sensor frame** (TI's point-cloud convention): ``x`` along the antenna
  array (the library's local x), ``y`` along the boresight, ``z`` up on the
  board. Spherical: ``x = r cos(el) sin(az)``, ``y = r cos(el) cos(az)``,
  ``z = r sin(el)``.
- **level frame**: the same origin, rotated about ``x`` so that ``Z`` is
  vertical. A board tilted *down* by ``tilt_rad`` (> 0) has its boresight
  along ``(0, cos t, -sin t)`` and its ``z`` along ``(0, sin t, cos t)``::

      X = x,  Y = y cos t + z sin t,  Z = -y sin t + z cos t.

  ``(X, Y)`` are the node's 2D local coordinates (docs/CONVENTIONS.md:
  local x along the array axis, local y along broadside); ``Z + height_m`` is
  the height above the floor.
- **room frame**: global ``(x, y)`` with the floor at ``z = 0``; a node at
  2D pose ``(x_m, y_m, phi_rad)`` and ``height_m`` (some recording tools store
  points this way after applying a nominal mounting).

The plane measurement of a point is ``range_m = hypot(X, Y)``,
``omega_rad = pi X / range_m`` (``pi sin`` of the horizontal azimuth) and,
for a target moving horizontally, ``doppler_mps = doppler_3d * r3 / range_m``
with ``r3 = |(x, y, z)|``: the radial speed ``<v, p> / r3`` with ``v_Z = 0``
is ``<v_h, p_h> / r3``, and the 2D model's Doppler is ``<v_h, p_h> / range``.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["PlaneProjection", "spherical_to_cartesian", "cartesian_to_spherical",
           "sensor_to_level", "level_to_sensor", "room_to_sensor", "sensor_to_room",
           "project_to_plane", "MIN_HORIZONTAL_RANGE_M"]

#: Points closer than this to the vertical through the sensor have no
#: horizontal azimuth; they are dropped.
MIN_HORIZONTAL_RANGE_M = 1e-6


class PlaneProjection(NamedTuple):
    """Projection of K points: ``range_m, omega_rad, doppler_mps`` (K,) in the
    node's 2D plane, ``height_m`` (K,) above the floor, ``keep`` (K,) bool:
    inside the height band and off the sensor's vertical."""

    range_m: NDArray
    omega_rad: NDArray
    doppler_mps: NDArray
    height_m: NDArray
    keep: NDArray


def spherical_to_cartesian(range_m: ArrayLike, azimuth_rad: ArrayLike,
                           elevation_rad: ArrayLike) -> NDArray:
    """TI spherical ``(r, az, el)`` -> sensor ``(..., 3)`` Cartesian points."""
    r = np.asarray(range_m, dtype=float)
    az = np.asarray(azimuth_rad, dtype=float)
    el = np.asarray(elevation_rad, dtype=float)
    return np.stack([r * np.cos(el) * np.sin(az), r * np.cos(el) * np.cos(az),
                     r * np.sin(el)], axis=-1)


def cartesian_to_spherical(points_xyz: ArrayLike) -> tuple[NDArray, NDArray, NDArray]:
    """Inverse of :func:`spherical_to_cartesian`: ``(range_m, azimuth_rad, elevation_rad)``."""
    p = np.asarray(points_xyz, dtype=float)
    r = np.linalg.norm(p, axis=-1)
    az = np.arctan2(p[..., 0], p[..., 1])
    el = np.arctan2(p[..., 2], np.hypot(p[..., 0], p[..., 1]))
    return r, az, el


def sensor_to_level(points_xyz: ArrayLike, tilt_rad: ArrayLike) -> NDArray:
    """Sensor-frame points ``(..., 3)`` -> the level frame, for a board tilted
    down by ``tilt_rad`` (module docstring)."""
    p = np.asarray(points_xyz, dtype=float)
    c, s = np.cos(tilt_rad), np.sin(tilt_rad)
    return np.stack([p[..., 0], c * p[..., 1] + s * p[..., 2],
                     -s * p[..., 1] + c * p[..., 2]], axis=-1)


def level_to_sensor(points_xyz: ArrayLike, tilt_rad: ArrayLike) -> NDArray:
    """Inverse of :func:`sensor_to_level`."""
    p = np.asarray(points_xyz, dtype=float)
    c, s = np.cos(tilt_rad), np.sin(tilt_rad)
    return np.stack([p[..., 0], c * p[..., 1] - s * p[..., 2],
                     s * p[..., 1] + c * p[..., 2]], axis=-1)


def room_to_sensor(points_xyz: ArrayLike, node_pose: ArrayLike, height_m: float,
                   tilt_rad: float) -> NDArray:
    """Room-frame points ``(..., 3)`` -> a node's sensor frame, given its
    nominal mounting: 2D pose ``(x_m, y_m, phi_rad)``, height and down tilt."""
    p = np.asarray(points_xyz, dtype=float)
    pose = np.asarray(node_pose, dtype=float)
    c, s = np.cos(pose[..., 2]), np.sin(pose[..., 2])
    dx, dy = p[..., 0] - pose[..., 0], p[..., 1] - pose[..., 1]
    level = np.stack([c * dx + s * dy, -s * dx + c * dy, p[..., 2] - height_m], axis=-1)
    return level_to_sensor(level, tilt_rad)


def sensor_to_room(points_xyz: ArrayLike, node_pose: ArrayLike, height_m: float,
                   tilt_rad: float) -> NDArray:
    """Inverse of :func:`room_to_sensor`."""
    level = sensor_to_level(points_xyz, tilt_rad)
    pose = np.asarray(node_pose, dtype=float)
    c, s = np.cos(pose[..., 2]), np.sin(pose[..., 2])
    return np.stack([pose[..., 0] + c * level[..., 0] - s * level[..., 1],
                     pose[..., 1] + s * level[..., 0] + c * level[..., 1],
                     level[..., 2] + height_m], axis=-1)


def project_to_plane(points_xyz: ArrayLike, doppler_mps: ArrayLike, *, height_m: float = 0.0,
                     tilt_rad: float = 0.0,
                     height_band_m: tuple[float, float] | None = None) -> PlaneProjection:
    """Project sensor-frame points ``(K, 3)`` with radial Doppler ``(K,)`` into
    the node's 2D measurement plane (module docstring).

    height_m : mounting height of the sensor above the floor; tilt_rad : down
    tilt (> 0 = looking down). height_band_m : ``(low, high)`` heights above
    the floor to keep (e.g. ``(0.2, 2.0)`` drops floor and ceiling points);
    None keeps all heights. Shapes of the outputs never depend on the band:
    see ``keep``.
    """
    p = np.asarray(points_xyz, dtype=float)
    level = sensor_to_level(p, tilt_rad)
    rng = np.hypot(level[..., 0], level[..., 1])
    keep = rng > MIN_HORIZONTAL_RANGE_M
    safe = np.where(keep, rng, 1.0)
    omega = np.where(keep, np.pi * np.clip(level[..., 0] / safe, -1.0, 1.0), 0.0)
    r3 = np.linalg.norm(p, axis=-1)
    doppler = np.where(keep, np.asarray(doppler_mps, dtype=float) * r3 / safe, 0.0)
    height = level[..., 2] + height_m
    if height_band_m is not None:
        low, high = height_band_m
        keep = keep & (height >= low) & (height <= high)
    return PlaneProjection(range_m=rng, omega_rad=omega, doppler_mps=doppler, height_m=height,
                           keep=keep)
