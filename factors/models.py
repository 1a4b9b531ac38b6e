"""Radar measurement models as pure, vectorized numpy functions (docs/CONVENTIONS.md).

Every estimator in the project (GTSAM factors, the batch solver, the bounds,
the EKF) and the simulator call these functions: one model, one place.

Conventions (docs/CONVENTIONS.md, "Frames and poses"):

- a node pose is ``(x_m, y_m, phi_rad)``; ``phi`` is the direction of the array
  axis ``mu = (cos phi, sin phi)``; the node's local frame has its x-axis along
  the array axis and its y-axis along broadside;
- a target state is ``(x_m, y_m, vx_mps, vy_mps)`` in the global frame;
- a measurement is ``(range_m, omega_rad, doppler_mps)`` with
  ``omega = pi sin(theta) = pi <d, mu> / r`` and ``doppler = <v, d> / r``
  (positive = receding), ``d = p - p_node``, ``r = |d|``.

All functions broadcast over leading axes: ``state (..., 4)`` against
``node_pose (..., 3)``. They do not validate (they sit in hot loops); the
public entry points of :mod:`mmsnap_graph` validate.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "MEASUREMENT_NAMES",
    "wrap_angle",
    "range_model",
    "omega_model",
    "doppler_model",
    "measurement_model",
    "measurement_model_pose",
    "measurement_model_scalar",
    "predict_measurements",
    "wrap_angle_scalar",
    "residual",
    "detection_to_local",
    "local_to_global",
    "global_to_local",
    "detection_to_global",
]

#: Order of the components of a measurement vector.
MEASUREMENT_NAMES = ("range_m", "omega_rad", "doppler_mps")


def wrap_angle(angle_rad: ArrayLike) -> NDArray:
    """Wrap angles to ``[-pi, pi)``; the one helper for every angle residual."""
    a = np.asarray(angle_rad, dtype=float)
    return (a + np.pi) % (2.0 * np.pi) - np.pi


def _geometry(state: NDArray, node_pose: NDArray):
    d = state[..., :2] - node_pose[..., :2]
    r = np.sqrt(d[..., 0] ** 2 + d[..., 1] ** 2)
    u = d / r[..., None]
    mu = np.stack([np.cos(node_pose[..., 2]), np.sin(node_pose[..., 2])], axis=-1)
    return d, r, u, mu


def range_model(state: ArrayLike, node_pose: ArrayLike) -> tuple[NDArray, NDArray]:
    """Range of targets from a node, ``R = |p - p_i|`` (paper eq. 5).

    state : (..., 4) float, ``(x_m, y_m, vx_mps, vy_mps)``, global frame.
    node_pose : (..., 3) float, ``(x_m, y_m, phi_rad)``.
    Returns ``range_m (...,)`` and ``d range / d state (..., 4)``.
    """
    state = np.asarray(state, dtype=float)
    node_pose = np.asarray(node_pose, dtype=float)
    _, r, u, _ = _geometry(state, node_pose)
    jac = np.concatenate([u, np.zeros_like(u)], axis=-1)
    return r, jac


def omega_model(state: ArrayLike, node_pose: ArrayLike) -> tuple[NDArray, NDArray]:
    """Spatial frequency ``Omega = pi <d, mu> / r = pi sin(theta)`` (eq. 7, with its pi).

    Returns ``omega_rad (...,)`` and ``d omega / d state (..., 4)``:
    ``d Omega / d p = (pi / r) (mu - (<d, mu> / r) u)``.
    """
    state = np.asarray(state, dtype=float)
    node_pose = np.asarray(node_pose, dtype=float)
    d, r, u, mu = _geometry(state, node_pose)
    s = np.sum(d * mu, axis=-1) / r
    dp = (np.pi / r)[..., None] * (mu - s[..., None] * u)
    jac = np.concatenate([dp, np.zeros_like(dp)], axis=-1)
    return np.pi * s, jac


def doppler_model(state: ArrayLike, node_pose: ArrayLike) -> tuple[NDArray, NDArray]:
    """Radial velocity ``V = <v, d> / r``, positive when receding (eq. 6).

    Returns ``doppler_mps (...,)`` and ``d V / d state (..., 4)``:
    ``d V / d p = (v - V u) / r``, ``d V / d v = u``.
    """
    state = np.asarray(state, dtype=float)
    node_pose = np.asarray(node_pose, dtype=float)
    _, r, u, _ = _geometry(state, node_pose)
    vel = state[..., 2:]
    v = np.sum(vel * u, axis=-1)
    jac = np.concatenate([(vel - v[..., None] * u) / r[..., None], u], axis=-1)
    return v, jac


def measurement_model(state: ArrayLike, node_pose: ArrayLike) -> tuple[NDArray, NDArray]:
    """All three measurements of a target from a node with a known pose (form a).

    state : (..., 4) float, global frame.
    node_pose : (..., 3) float.
    Returns ``h (..., 3)`` = (range_m, omega_rad, doppler_mps) and the
    Jacobian ``d h / d state (..., 3, 4)``.
    """
    state = np.asarray(state, dtype=float)
    node_pose = np.asarray(node_pose, dtype=float)
    # Component-wise into preallocated outputs: this function is the batch
    # solver's inner loop, and stacking temporaries cost it ~40% of its time.
    dx = state[..., 0] - node_pose[..., 0]
    dy = state[..., 1] - node_pose[..., 1]
    r = np.sqrt(dx * dx + dy * dy)
    ux = dx / r
    uy = dy / r
    c = np.cos(node_pose[..., 2])
    s = (dx * c + dy * np.sin(node_pose[..., 2])) / r      # sin(theta) = <d, mu> / r
    vx = state[..., 2]
    vy = state[..., 3]
    v = vx * ux + vy * uy
    k = np.pi / r
    shape = r.shape
    h = np.empty(shape + (3,))
    h[..., 0] = r
    h[..., 1] = np.pi * s
    h[..., 2] = v
    jac = np.zeros(shape + (3, 4))
    jac[..., 0, 0] = ux
    jac[..., 0, 1] = uy
    jac[..., 1, 0] = k * (c - s * ux)
    jac[..., 1, 1] = k * (np.sin(node_pose[..., 2]) - s * uy)
    jac[..., 2, 0] = (vx - v * ux) / r
    jac[..., 2, 1] = (vy - v * uy) / r
    jac[..., 2, 2] = ux
    jac[..., 2, 3] = uy
    return h, jac


def predict_measurements(state: ArrayLike, node_pose: ArrayLike) -> NDArray:
    """The prediction ``h (..., 3)`` of :func:`measurement_model` without the
    Jacobian: ~20x cheaper over large grids of states (the grid posterior
    evaluates ~10^5 states per frame). Same formulas; tested equal.

    state : (..., 4) float; node_pose : (..., 3) float. Returns
    ``(range_m, omega_rad, doppler_mps)`` as ``(..., 3)``.
    """
    state = np.asarray(state, dtype=float)
    node_pose = np.asarray(node_pose, dtype=float)
    dx = state[..., 0] - node_pose[..., 0]
    dy = state[..., 1] - node_pose[..., 1]
    r = np.sqrt(dx * dx + dy * dy)
    c = np.cos(node_pose[..., 2])
    s = np.sin(node_pose[..., 2])
    omega = np.pi * (dx * c + dy * s) / r
    doppler = (state[..., 2] * dx + state[..., 3] * dy) / r
    return np.stack(np.broadcast_arrays(r, omega, doppler), axis=-1)


def measurement_model_pose(
    node_pose: ArrayLike, state: ArrayLike
) -> tuple[NDArray, NDArray, NDArray]:
    """Measurements with an unknown node pose (form b, for calibration graphs).

    node_pose : (..., 3) float, ``(x_m, y_m, phi_rad)`` of a ``gtsam.Pose2``.
    state : (..., 4) float, target ``(x, y, vx, vy)`` in the global frame.
    Returns ``h (..., 3)``, ``d h / d pose (..., 3, 3)`` in GTSAM's body-frame
    tangent ``xi = (dx_b, dy_b, dphi)`` (``pose.retract(xi)``), and
    ``d h / d state (..., 3, 4)``.

    The pose Jacobian is ``[d h / d p_i @ R(phi_i), d h / d phi_i]``
    (docs/CONVENTIONS.md): GTSAM perturbs a Pose2 in its own frame.
    """
    node_pose = np.asarray(node_pose, dtype=float)
    state = np.asarray(state, dtype=float)
    h, j_state = measurement_model(state, node_pose)
    d, r, _, _ = _geometry(state, node_pose)
    # Every model depends on the node position only through d = p - p_i.
    dh_dpi = -j_state[..., :2]
    c = np.cos(node_pose[..., 2])[..., None]
    s = np.sin(node_pose[..., 2])[..., None]
    # (dh/dp_i) @ R(phi): columns [dh/dx cos + dh/dy sin, -dh/dx sin + dh/dy cos]
    body = np.stack(
        [dh_dpi[..., 0] * c + dh_dpi[..., 1] * s, -dh_dpi[..., 0] * s + dh_dpi[..., 1] * c],
        axis=-1,
    )
    # Only Omega depends on phi: d/dphi pi <d, mu> / r = pi <d, (-sin, cos)> / r.
    mu_perp = np.stack([-np.sin(node_pose[..., 2]), np.cos(node_pose[..., 2])], axis=-1)
    dphi = np.zeros(h.shape)
    dphi[..., 1] = np.pi * np.sum(d * mu_perp, axis=-1) / r
    j_pose = np.concatenate([body, dphi[..., None]], axis=-1)
    return h, j_pose, j_state


_PI = math.pi
_TWO_PI = 2.0 * math.pi


def wrap_angle_scalar(angle_rad: float) -> float:
    """:func:`wrap_angle` for one Python float (Python's ``%`` on floats takes
    the divisor's sign, as numpy's does), to ``[-pi, pi)``."""
    return (angle_rad + _PI) % _TWO_PI - _PI


def measurement_model_scalar(x, y, vx, vy, px, py, cos_phi, sin_phi):
    """:func:`measurement_model` for one target and one node in plain Python
    floats: the same formulas, for hot loops (GTSAM error callbacks) where
    numpy's per-call overhead on 3-vectors costs ~10x the arithmetic.

    Arguments are the state ``(x, y, vx, vy)`` and the node's position and
    array-axis direction ``(px, py, cos phi, sin phi)``. Returns
    ``(range_m, omega_rad, doppler_mps, jac)`` with ``jac`` the 3x4 Jacobian
    ``d h / d state`` flattened row-major into a 12-tuple (``jac[4 * k + j]``
    is ``d h_k / d state_j``). Raises ``ZeroDivisionError`` for a target at
    the node's position.
    """
    dx = x - px
    dy = y - py
    r = math.sqrt(dx * dx + dy * dy)
    ux = dx / r
    uy = dy / r
    sn = ux * cos_phi + uy * sin_phi
    v = vx * ux + vy * uy
    k = _PI / r
    return (
        r,
        _PI * sn,
        v,
        (
            ux, uy, 0.0, 0.0,
            k * (cos_phi - sn * ux), k * (sin_phi - sn * uy), 0.0, 0.0,
            (vx - v * ux) / r, (vy - v * uy) / r, ux, uy,
        ),
    )  # fmt: skip


def residual(predicted: ArrayLike, measured: ArrayLike) -> NDArray:
    """``predicted - measured`` over ``(..., 3)`` measurement vectors, the
    spatial-frequency component wrapped to ``[-pi, pi)``."""
    e = np.asarray(predicted, dtype=float) - np.asarray(measured, dtype=float)
    e = np.array(e, copy=True)
    e[..., 1] = wrap_angle(e[..., 1])
    return e


def detection_to_local(range_m: ArrayLike, omega_rad: ArrayLike) -> NDArray:
    """A detection in the node's local frame (docs/CONVENTIONS.md, initial values).

    ``(u, v) = (R Omega / pi, R sqrt(1 - (Omega / pi)^2))``; ``|Omega| > pi``
    is clipped to the array's end-fire direction. Returns ``(..., 2)`` metres.
    """
    rng = np.asarray(range_m, dtype=float)
    sin_theta = np.clip(np.asarray(omega_rad, dtype=float) / np.pi, -1.0, 1.0)
    return np.stack([rng * sin_theta, rng * np.sqrt(1.0 - sin_theta**2)], axis=-1)


def local_to_global(p_local: ArrayLike, node_pose: ArrayLike) -> NDArray:
    """``p = p_i + R(phi_i) p_local``, i.e. ``Pose2.transformFrom``; ``(..., 2)``."""
    p_local = np.asarray(p_local, dtype=float)
    node_pose = np.asarray(node_pose, dtype=float)
    c = np.cos(node_pose[..., 2])
    s = np.sin(node_pose[..., 2])
    x = node_pose[..., 0] + c * p_local[..., 0] - s * p_local[..., 1]
    y = node_pose[..., 1] + s * p_local[..., 0] + c * p_local[..., 1]
    return np.stack([x, y], axis=-1)


def global_to_local(p_global: ArrayLike, node_pose: ArrayLike) -> NDArray:
    """Inverse of :func:`local_to_global` (``Pose2.transformTo``); ``(..., 2)``."""
    p_global = np.asarray(p_global, dtype=float)
    node_pose = np.asarray(node_pose, dtype=float)
    c = np.cos(node_pose[..., 2])
    s = np.sin(node_pose[..., 2])
    dx = p_global[..., 0] - node_pose[..., 0]
    dy = p_global[..., 1] - node_pose[..., 1]
    return np.stack([c * dx + s * dy, -s * dx + c * dy], axis=-1)


def detection_to_global(
    range_m: ArrayLike, omega_rad: ArrayLike, node_pose: ArrayLike
) -> NDArray:
    """A detection mapped to the global frame (docs/CONVENTIONS.md, the corrected eq. 19)."""
    return local_to_global(detection_to_local(range_m, omega_rad), node_pose)
