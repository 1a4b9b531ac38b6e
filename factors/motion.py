"""Constant-velocity motion model of a target state ``(x, y, vx, vy)``
(docs/CONVENTIONS.md, "Constant-velocity motion model"): the one transition and process noise
used by the per-node EKF, the central tracker and the GTSAM motion factor.

Per axis, with ``T`` the time between two states and white acceleration of
standard deviation ``sigma_a``:

- transition ``F = [[1, T], [0, 1]]``;
- discrete white-acceleration noise (the acceleration constant over ``T``,
  ``G = (T^2 / 2, T)``): ``Q = sigma_a^2 G G^T = sigma_a^2 [[T^4/4, T^3/2],
  [T^3/2, T^2]]``, rank one per axis (the Kalman filters);
- continuous white-noise acceleration of spectral density ``q``:
  ``Q = q [[T^3/3, T^2/2], [T^2/2, T]]`` (the integral of
  ``F(s) G G^T F(s)^T q`` over ``[0, T]`` with ``G = (0, 1)``), full rank, so
  that it can whiten a factor. With ``q = sigma_a^2 T`` the velocity
  increment has the same variance ``sigma_a^2 T^2`` as in the discrete form
  (the GTSAM factor).

Pure numpy; nothing here validates (callers sit in per-frame loops).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["cv_transition", "cv_process_noise", "cv_process_noise_continuous"]


def cv_transition(frame_period_s: float) -> NDArray:
    """(4, 4) constant-velocity transition over ``frame_period_s`` for state
    ``(x, y, vx, vy)``."""
    f = np.eye(4)
    f[0, 2] = f[1, 3] = frame_period_s
    return f


def _per_axis(block: NDArray) -> NDArray:
    """(2, 2) ``[[pos, pos-vel], [vel-pos, vel]]`` block -> (4, 4) for ``(x, y, vx, vy)``."""
    q = np.zeros((4, 4))
    q[0::2, 0::2] = block
    q[1::2, 1::2] = block
    return q


def cv_process_noise(frame_period_s: float, sigma_a_mps2: float) -> NDArray:
    """(4, 4) discrete white-acceleration process noise
    ``sigma_a^2 [[T^4/4, T^3/2], [T^3/2, T^2]]`` per axis, ordered ``(x, y, vx, vy)``."""
    t = float(frame_period_s)
    g = np.array([t * t / 2.0, t])
    return _per_axis(float(sigma_a_mps2) ** 2 * np.outer(g, g))


def cv_process_noise_continuous(frame_period_s: float, sigma_a_mps2: float) -> NDArray:
    """(4, 4) continuous white-noise acceleration covariance
    ``q [[T^3/3, T^2/2], [T^2/2, T]]`` per axis with ``q = sigma_a^2 T``
    (module docstring), ordered ``(x, y, vx, vy)``; full rank for ``T > 0``."""
    t = float(frame_period_s)
    q = float(sigma_a_mps2) ** 2 * t
    return _per_axis(q * np.array([[t**3 / 3.0, t**2 / 2.0], [t**2 / 2.0, t]]))
