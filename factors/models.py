"""Radar measurement models as pure, vectorized numpy functions (docs/CONVENTIONS.md).

Every estimator in the project (GTSAM factors, the batch solver, the bounds,
the EKF) and the simulator call these functions: one model, one place. The
formulas of h(x) live in one private helper; the model has three public forms
built on it: :func:`measurement_model` (vectorized, known node pose; its
prediction alone is :func:`predict_measurements`), :func:`measurement_model_pose`
(unknown pose, Pose2 body tangent) and :func:`measurement_model_scalar` (plain
floats for GTSAM callbacks; tested equal to the vectorized form). The inverse of
a detection (range, spatial frequency) to a local position, its Jacobian and
its covariance are here too (``detection_*``).

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
    "measurement_model",
    "measurement_model_pose",
    "measurement_model_scalar",
    "predict_measurements",
    "wrap_angle_scalar",
    "residual",
    "DETECTION_MIN_COS",
    "detection_to_local",
    "detection_to_local_scalar",
    "detection_jacobian",
    "detection_covariance_local",
    "detection_covariance_global",
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


def _predict(state: NDArray, node_pose: NDArray):
    """The one place the measurement formulas live: ``h (..., 3)`` and the
    geometry the Jacobians are built from (``u = d / r`` with ``d = p - p_i``,
    ``r = |d|``; ``mu = (cos phi, sin phi)``; ``sin(theta) = <u, mu>``).

    Written for speed (the batch solver's inner loop, and ~10^5 grid states
    per frame in the grid posterior): component-wise, accumulating in place,
    into a preallocated output (stacking temporaries cost ~40%)."""
    dx = state[..., 0] - node_pose[..., 0]
    dy = state[..., 1] - node_pose[..., 1]
    r = np.sqrt(dx * dx + dy * dy)
    ux = dx / r
    uy = dy / r
    c = np.cos(node_pose[..., 2])
    s = np.sin(node_pose[..., 2])
    vx = state[..., 2]
    vy = state[..., 3]
    sn = ux * c                              # sin(theta) = <u, mu>
    sn += uy * s
    v = vx * ux                              # <v, u>, positive receding
    v += vy * uy
    h = np.empty(r.shape + (3,))
    h[..., 0] = r
    np.multiply(sn, np.pi, out=h[..., 1])
    h[..., 2] = v
    return h, (ux, uy, r, c, s, sn, vx, vy, v)


def measurement_model(state: ArrayLike, node_pose: ArrayLike) -> tuple[NDArray, NDArray]:
    """All three measurements of a target from a node with a known pose (form a).

    state : (..., 4) float, global frame.
    node_pose : (..., 3) float.
    Returns ``h (..., 3)`` = (range_m, omega_rad, doppler_mps) (paper eqs.
    5-7) and the Jacobian ``d h / d state (..., 3, 4)``:
    ``d R / d p = u``; ``d Omega / d p = (pi / r) (mu - sin(theta) u)``;
    ``d V / d p = (v - V u) / r``, ``d V / d v = u`` (``u = d / r``).
    """
    state = np.asarray(state, dtype=float)
    node_pose = np.asarray(node_pose, dtype=float)
    h, (ux, uy, r, c, s, sn, vx, vy, v) = _predict(state, node_pose)
    k = np.pi / r
    jac = np.zeros(r.shape + (3, 4))
    jac[..., 0, 0] = ux
    jac[..., 0, 1] = uy
    jac[..., 1, 0] = k * (c - sn * ux)
    jac[..., 1, 1] = k * (s - sn * uy)
    jac[..., 2, 0] = (vx - v * ux) / r
    jac[..., 2, 1] = (vy - v * uy) / r
    jac[..., 2, 2] = ux
    jac[..., 2, 3] = uy
    return h, jac


def predict_measurements(state: ArrayLike, node_pose: ArrayLike) -> NDArray:
    """The prediction ``h (..., 3)`` of :func:`measurement_model` without the
    Jacobian (the same private formulas), for large grids of states (the grid
    posterior evaluates ~10^5 states per frame).

    state : (..., 4) float; node_pose : (..., 3) float. Returns
    ``(range_m, omega_rad, doppler_mps)`` as ``(..., 3)``.
    """
    return _predict(np.asarray(state, dtype=float), np.asarray(node_pose, dtype=float))[0]


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
    c = np.cos(node_pose[..., 2])[..., None]
    s = np.sin(node_pose[..., 2])[..., None]
    # Every model depends on the node position only through d = p - p_i, so
    # d h / d p_i = -d h / d p; (d h / d p_i) @ R(phi) in the body tangent.
    a = -j_state[..., 0]
    b = -j_state[..., 1]
    j_pose = np.zeros(h.shape + (3,))
    j_pose[..., 0] = a * c + b * s
    j_pose[..., 1] = -a * s + b * c
    # Only Omega depends on phi: pi <u, (-sin phi, cos phi)> = pi cos(theta).
    ux = j_state[..., 0, 0]
    uy = j_state[..., 0, 1]
    j_pose[..., 1, 2] = np.pi * (uy * c[..., 0] - ux * s[..., 0])
    return h, j_pose, j_state


_PI = math.pi
_TWO_PI = 2.0 * math.pi


def wrap_angle_scalar(angle_rad: float) -> float:
    """:func:`wrap_angle` for one Python float (Python's ``%`` on floats takes
    the divisor's sign, as numpy's does), to ``[-pi, pi)``."""
    return (angle_rad + _PI) % _TWO_PI - _PI


def measurement_model_scalar(x, y, vx, vy, px, py, cos_phi, sin_phi, pose_jacobian=False):
    """:func:`measurement_model` for one target and one node in plain Python
    floats: the same formulas, for hot loops (GTSAM error callbacks) where
    numpy's per-call overhead on 3-vectors costs ~10x the arithmetic.

    Arguments are the state ``(x, y, vx, vy)`` and the node's position and
    array-axis direction ``(px, py, cos phi, sin phi)``. Returns
    ``(range_m, omega_rad, doppler_mps, jac)`` with ``jac`` the 3x4 Jacobian
    ``d h / d state`` flattened row-major into a 12-tuple (``jac[4 * k + j]``
    is ``d h_k / d state_j``). With ``pose_jacobian=True`` a fifth item
    follows: the 3x3 Jacobian ``d h / d pose`` in the Pose2 body tangent (as
    :func:`measurement_model_pose`), flattened row-major into a 9-tuple.
    Raises ``ZeroDivisionError`` for a target at the node's position.
    """
    dx = x - px
    dy = y - py
    r = math.sqrt(dx * dx + dy * dy)
    ux = dx / r
    uy = dy / r
    sn = ux * cos_phi + uy * sin_phi
    v = vx * ux + vy * uy
    k = _PI / r
    jac = (
        ux, uy, 0.0, 0.0,
        k * (cos_phi - sn * ux), k * (sin_phi - sn * uy), 0.0, 0.0,
        (vx - v * ux) / r, (vy - v * uy) / r, ux, uy,
    )  # fmt: skip
    if not pose_jacobian:
        return r, _PI * sn, v, jac
    jvx = jac[8]
    jvy = jac[9]
    # d h / d pose = [-(d h / d p) @ R(phi), d h / d phi]; cs = cos(theta).
    cs = uy * cos_phi - ux * sin_phi
    j_pose = (
        -sn, -cs, 0.0,
        -k * (1.0 - sn * sn), k * sn * cs, _PI * cs,
        -(jvx * cos_phi + jvy * sin_phi), jvx * sin_phi - jvy * cos_phi, 0.0,
    )  # fmt: skip
    return r, _PI * sn, v, jac, j_pose


def residual(predicted: ArrayLike, measured: ArrayLike) -> NDArray:
    """``predicted - measured`` over ``(..., 3)`` measurement vectors, the
    spatial-frequency component wrapped to ``[-pi, pi)``."""
    e = np.asarray(predicted, dtype=float) - np.asarray(measured, dtype=float)
    e = np.array(e, copy=True)
    e[..., 1] = wrap_angle(e[..., 1])
    return e


#: Floor of ``cos(theta) = sqrt(1 - (Omega / pi)^2)`` in the detection
#: Jacobian and covariances: at end-fire the spatial-frequency derivative of
#: the cross-range coordinate diverges; the floor keeps covariances finite
#: (exact for ``|theta| <= 87.1 deg``).
DETECTION_MIN_COS = 0.05


def detection_to_local(range_m: ArrayLike, omega_rad: ArrayLike) -> NDArray:
    """A detection in the node's local frame (docs/CONVENTIONS.md, initial values).

    ``(u, v) = (R s, R sqrt(1 - s^2))`` with ``s = sin(theta) = Omega / pi``;
    ``|Omega| > pi`` (noise beyond the array's end-fire) is clipped to
    ``s = +-1``, the end-fire direction. Returns ``(..., 2)`` metres.
    """
    rng = np.asarray(range_m, dtype=float)
    sin_theta = np.clip(np.asarray(omega_rad, dtype=float) / np.pi, -1.0, 1.0)
    return np.stack([rng * sin_theta, rng * np.sqrt(1.0 - sin_theta**2)], axis=-1)


def detection_to_local_scalar(range_m: float, omega_rad: float) -> tuple[float, float]:
    """:func:`detection_to_local` for one detection in plain Python floats
    (per-frame hot paths); the same clipping. Returns ``(u_m, v_m)``."""
    st = min(max(omega_rad / _PI, -1.0), 1.0)
    return range_m * st, range_m * math.sqrt(1.0 - st * st)


def detection_jacobian(
    range_m: ArrayLike, omega_rad: ArrayLike, min_cos: float = DETECTION_MIN_COS
) -> NDArray:
    """``d p_local / d (range_m, omega_rad)`` of :func:`detection_to_local`, (..., 2, 2).

    Columns: ``d p / d R = (s, c)``, ``d p / d Omega = (R / pi) (1, -s / c)``
    with ``s = Omega / pi`` clipped as in :func:`detection_to_local` and
    ``c = sqrt(1 - s^2)`` floored at ``min_cos`` (:data:`DETECTION_MIN_COS`).
    """
    rng = np.asarray(range_m, dtype=float)
    s = np.clip(np.asarray(omega_rad, dtype=float) / np.pi, -1.0, 1.0)
    c = np.maximum(np.sqrt(1.0 - s**2), min_cos)
    k = rng / np.pi
    jac = np.empty(np.broadcast_shapes(rng.shape, s.shape) + (2, 2))
    jac[..., 0, 0] = s
    jac[..., 1, 0] = c
    jac[..., 0, 1] = k
    jac[..., 1, 1] = -k * s / c
    return jac


def detection_covariance_local(
    range_m: ArrayLike,
    omega_rad: ArrayLike,
    range_sigma_m: float,
    omega_sigma_rad: float,
    min_cos: float = DETECTION_MIN_COS,
) -> NDArray:
    """First-order covariance ``J diag(sigma_R^2, sigma_Omega^2) J^T`` of
    detections in the node's local frame, (..., 2, 2) m^2
    (``J`` = :func:`detection_jacobian`)."""
    jac = detection_jacobian(range_m, omega_rad, min_cos)
    var = np.array([float(range_sigma_m) ** 2, float(omega_sigma_rad) ** 2])
    return (jac * var) @ np.swapaxes(jac, -1, -2)


def detection_covariance_global(
    range_m: ArrayLike,
    omega_rad: ArrayLike,
    node_pose: ArrayLike,
    range_sigma_m: float,
    omega_sigma_rad: float,
    min_cos: float = DETECTION_MIN_COS,
) -> NDArray:
    """:func:`detection_covariance_local` rotated into the global frame,
    ``R(phi_i) C R(phi_i)^T``, (..., 2, 2) m^2; node_pose (..., 3) or (3,)."""
    cov = detection_covariance_local(range_m, omega_rad, range_sigma_m, omega_sigma_rad, min_cos)
    pose = np.asarray(node_pose, dtype=float)
    cp, sp = np.cos(pose[..., 2]), np.sin(pose[..., 2])
    rot = np.empty(cp.shape + (2, 2))
    rot[..., 0, 0] = cp
    rot[..., 0, 1] = -sp
    rot[..., 1, 0] = sp
    rot[..., 1, 1] = cp
    return rot @ cov @ np.swapaxes(rot, -1, -2)


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
