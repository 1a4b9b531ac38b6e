"""Thin GTSAM adapters around :mod:`factors.models`.

Each factor is a ``gtsam.CustomFactor`` whose error function calls the model
and returns the *unwhitened* error ``h(x) - z`` (spatial frequency wrapped);
the noise model carries the sigmas. The measurement factors call
:func:`factors.models.measurement_model_scalar`, the plain-float twin of
:func:`factors.models.measurement_model` (tested equal to rounding): GTSAM
calls the error function once per linearization and per error evaluation, and
numpy's per-call overhead on 3-vectors would cost ~10x the arithmetic. The measurement is bound with
``functools.partial``, as in GTSAM's own Python examples.

Variables:

- target state: a ``Vector4`` ``(x_m, y_m, vx_mps, vy_mps)`` (``values.atVector``);
- node pose (calibration graphs only): a ``gtsam.Pose2``;
- node clock offset (calibration graphs only): a ``Vector1`` in seconds
  (:func:`timed_pose_measurement_factor`).
"""

from __future__ import annotations

import math
from functools import partial
from typing import Sequence

import gtsam
import numpy as np
from numpy.typing import ArrayLike

from .models import measurement_model_scalar as _model_scalar
from .models import wrap_angle_scalar as _wrap_scalar
from .motion import cv_process_noise_continuous, cv_transition
from .robust import robust_k as _robust_k

__all__ = [
    "COMPONENT_INDEX",
    "measurement_noise",
    "node_measurement_factor",
    "frame_measurement_factor",
    "scalar_measurement_factor",
    "pose_measurement_factor",
    "timed_pose_measurement_factor",
    "state_prior_factor",
    "constant_velocity_factor",
]

#: Index of each measurement component in a measurement vector.
COMPONENT_INDEX = {"range": 0, "omega": 1, "doppler": 2}



def measurement_noise(
    sigmas: ArrayLike, robust: str | None = None, robust_k: float | None = None
) -> gtsam.noiseModel.Base:
    """Diagonal noise model, optionally wrapped in a Huber or Cauchy kernel
    (``robust_k`` default: :data:`factors.robust.ROBUST_K_DEFAULT`, Huber
    1.345, Cauchy 2.5 on the whitened residual)."""
    base = gtsam.noiseModel.Diagonal.Sigmas(np.asarray(sigmas, dtype=float))
    if robust is None:
        return base
    k = _robust_k(robust, robust_k)
    if robust == "huber":
        kernel = gtsam.noiseModel.mEstimator.Huber.Create(k)
    else:
        kernel = gtsam.noiseModel.mEstimator.Cauchy.Create(k)
    return gtsam.noiseModel.Robust.Create(kernel, base)


def _node_error(key, node, z, rows, this, values, jacobians):
    x, y, vx, vy = values.atVector(key).tolist()
    r, w, v, jac = _model_scalar(x, y, vx, vy, *node)
    err = np.array((r - z[0], _wrap_scalar(w - z[1]), v - z[2]))
    if rows is None:
        if jacobians is not None:
            jacobians[0] = np.array(jac).reshape(3, 4)
        return err
    if jacobians is not None:
        jacobians[0] = np.array(jac).reshape(3, 4)[rows]
    return err[rows]


def node_measurement_factor(
    state_key: int,
    node_pose: ArrayLike,
    measurement: ArrayLike,
    noise: gtsam.noiseModel.Base,
    components: Sequence[str] = ("range", "omega", "doppler"),
) -> gtsam.CustomFactor:
    """Range, spatial-frequency and Doppler factor of one node on a target state.

    node_pose : (3,) known ``(x_m, y_m, phi_rad)``.
    measurement : (3,) ``(range_m, omega_rad, doppler_mps)``.
    noise : a noise model of dimension ``len(components)``.
    components : which measurements to use (a subset keeps its order).
    """
    rows = np.array([COMPONENT_INDEX[c] for c in components])
    if rows.tolist() == [0, 1, 2]:
        rows = None  # the common case skips the row selection
    pose = np.asarray(node_pose, dtype=float).tolist()
    # The node pose enters the callback as (x, y, cos phi, sin phi) floats.
    node = (pose[0], pose[1], math.cos(pose[2]), math.sin(pose[2]))
    z = tuple(np.asarray(measurement, dtype=float).tolist())
    fn = partial(_node_error, state_key, node, z, rows)
    return gtsam.CustomFactor(noise, [state_key], fn)


def _frame_error(key, nodes, zs, this, values, jacobians):
    x, y, vx, vy = values.atVector(key).tolist()
    err = []
    jac = []
    for (px, py, c, s), (zr, zw, zv) in zip(nodes, zs):
        r, w, v, j = _model_scalar(x, y, vx, vy, px, py, c, s)
        err += (r - zr, _wrap_scalar(w - zw), v - zv)
        jac += j
    if jacobians is not None:
        jacobians[0] = np.array(jac).reshape(-1, 4)
    return np.array(err)


def frame_measurement_factor(
    state_key: int,
    node_poses: ArrayLike,
    measurements: ArrayLike,
    noise: gtsam.noiseModel.Base,
) -> gtsam.CustomFactor:
    """All nodes' range, spatial-frequency and Doppler measurements of one
    target state in one factor (the one-shot fusion graph, paper eq. 18).

    Equivalent to one :func:`node_measurement_factor` per node, but GTSAM
    calls one Python error function per evaluation instead of N, which
    halves the per-frame cost of one-shot fusion with two nodes.

    node_poses : (N, 3) known ``(x_m, y_m, phi_rad)``.
    measurements : (N, 3) ``(range_m, omega_rad, doppler_mps)``.
    noise : a noise model of dimension ``3 N``; the error is the stacked
        ``(h_i(x) - z_i)``, node after node, spatial frequency wrapped.
    """
    poses = np.asarray(node_poses, dtype=float).reshape(-1, 3).tolist()
    nodes = tuple((p[0], p[1], math.cos(p[2]), math.sin(p[2])) for p in poses)
    zs = tuple(tuple(row) for row in np.asarray(measurements, dtype=float).reshape(-1, 3).tolist())
    if len(zs) != len(nodes):
        raise ValueError(
            f"measurements has {len(zs)} rows but node_poses has {len(nodes)}: one per node"
        )
    return gtsam.CustomFactor(noise, [state_key], partial(_frame_error, state_key, nodes, zs))


def scalar_measurement_factor(
    state_key: int, node_pose: ArrayLike, component: str, value: float, sigma: float
) -> gtsam.CustomFactor:
    """A single range, spatial-frequency or Doppler factor (component in
    ``{"range", "omega", "doppler"}``)."""
    z = np.zeros(3)
    z[COMPONENT_INDEX[component]] = value
    return node_measurement_factor(
        state_key, node_pose, z, gtsam.noiseModel.Isotropic.Sigma(1, float(sigma)), (component,)
    )


def _pose_error(pose_key, state_key, z, this, values, jacobians):
    pose = values.atPose2(pose_key)
    x, y, vx, vy = values.atVector(state_key).tolist()
    phi = pose.theta()
    c = math.cos(phi)
    s = math.sin(phi)
    if jacobians is None:
        r, w, v, _ = _model_scalar(x, y, vx, vy, pose.x(), pose.y(), c, s)
    else:
        r, w, v, jac, j_pose = _model_scalar(x, y, vx, vy, pose.x(), pose.y(), c, s, True)
        jacobians[0] = np.array(j_pose).reshape(3, 3)
        jacobians[1] = np.array(jac).reshape(3, 4)
    return np.array((r - z[0], _wrap_scalar(w - z[1]), v - z[2]))


def pose_measurement_factor(
    pose_key: int, state_key: int, measurement: ArrayLike, noise: gtsam.noiseModel.Base
) -> gtsam.CustomFactor:
    """Measurement factor between an unknown node ``Pose2`` and a target state
    (form b, for calibration graphs). The pose Jacobian is in GTSAM's
    body-frame tangent."""
    fn = partial(_pose_error, pose_key, state_key, tuple(np.asarray(measurement, dtype=float).tolist()))
    return gtsam.CustomFactor(noise, [pose_key, state_key], fn)


def _timed_pose_error(pose_key, state_key, offset_key, z, this, values, jacobians):
    pose = values.atPose2(pose_key)
    x, y, vx, vy = values.atVector(state_key).tolist()
    tau = float(values.atVector(offset_key)[0])
    phi = pose.theta()
    c = math.cos(phi)
    s = math.sin(phi)
    # The state tau seconds later by the CV transition F(tau): the velocity
    # is unchanged, the position moves by tau * v.
    xs = x + tau * vx
    ys = y + tau * vy
    if jacobians is None:
        r, w, v, _ = _model_scalar(xs, ys, vx, vy, pose.x(), pose.y(), c, s)
    else:
        r, w, v, jac, j_pose = _model_scalar(xs, ys, vx, vy, pose.x(), pose.y(), c, s, True)
        j = np.array(jac).reshape(3, 4)  # d h / d (F(tau) x)
        j_state = j.copy()  # times F(tau): d/dvx += tau d/dx, d/dvy += tau d/dy
        j_state[:, 2] += tau * j[:, 0]
        j_state[:, 3] += tau * j[:, 1]
        jacobians[0] = np.array(j_pose).reshape(3, 3)
        jacobians[1] = j_state
        jacobians[2] = (j[:, 0] * vx + j[:, 1] * vy).reshape(3, 1)
    return np.array((r - z[0], _wrap_scalar(w - z[1]), v - z[2]))


def timed_pose_measurement_factor(
    pose_key: int, state_key: int, offset_key: int, measurement: ArrayLike,
    noise: gtsam.noiseModel.Base,
) -> gtsam.CustomFactor:
    """Measurement factor of a node with an unknown ``Pose2`` and an unknown
    clock offset ``tau`` (a ``Vector1`` in seconds) on the target state at
    the reference time of the measurement's frame (clock offsets in the
    joint calibration graph).

    The node measured at reference time ``t_k + tau`` (node time + offset =
    reference time): the prediction is ``h(F(tau) x_k, pose)`` with ``F`` the
    constant-velocity transition (:func:`factors.motion.cv_transition`).
    Jacobians: pose in GTSAM's body-frame tangent, state ``J F(tau)``, offset
    ``J[:, :2] v`` (``J`` the model's state Jacobian at ``F(tau) x_k``).
    """
    fn = partial(_timed_pose_error, pose_key, state_key, offset_key,
                 tuple(np.asarray(measurement, dtype=float).tolist()))
    return gtsam.CustomFactor(noise, [pose_key, state_key, offset_key], fn)


def state_prior_factor(
    state_key: int, mean: ArrayLike, sigmas: ArrayLike
) -> gtsam.PriorFactorVector:
    """Gaussian prior on a target state (paper eq. 16); a native GTSAM factor."""
    return gtsam.PriorFactorVector(
        state_key,
        np.asarray(mean, dtype=float),
        gtsam.noiseModel.Diagonal.Sigmas(np.asarray(sigmas, dtype=float)),
    )


def _cv_error(f, this, values, jacobians):
    keys = this.keys()
    a = values.atVector(keys[0])
    b = values.atVector(keys[1])
    if jacobians is not None:
        jacobians[0] = -f
        jacobians[1] = np.eye(4)
    return b - f @ a


def constant_velocity_factor(
    key_a: int, key_b: int, frame_period_s: float, sigma_a_mps2: float,
    robust: str | None = None, robust_k: float | None = None,
) -> gtsam.CustomFactor:
    """Constant-velocity motion factor between consecutive target states
    ``frame_period_s`` apart.

    The error is ``x_b - F x_a`` with ``F`` = :func:`factors.motion.cv_transition`.
    The discrete white-acceleration form of docs/CONVENTIONS.md,
    ``sigma_a^2 [[T^4/4, T^3/2], [T^3/2, T^2]]`` per axis, is rank one and
    cannot whiten a factor, so the factor uses the continuous white-noise
    acceleration form :func:`factors.motion.cv_process_noise_continuous`,
    ``q [[T^3/3, T^2/2], [T^2/2, T]]`` with ``q = sigma_a^2 T``, which gives
    the same velocity-increment variance ``sigma_a^2 T^2`` and is full rank.
    ``robust`` (``"huber"`` or ``"cauchy"``, width ``robust_k`` on the
    whitened 4-vector norm) puts a kernel on it: a sharp turn is not a
    Gaussian acceleration. Default: Gaussian.
    """
    t = float(frame_period_s)
    noise = gtsam.noiseModel.Gaussian.Covariance(cv_process_noise_continuous(t, sigma_a_mps2))
    if robust is not None:
        k = _robust_k(robust, robust_k)
        kernel = (gtsam.noiseModel.mEstimator.Huber.Create(k) if robust == "huber"
                  else gtsam.noiseModel.mEstimator.Cauchy.Create(k))
        noise = gtsam.noiseModel.Robust.Create(kernel, noise)
    return gtsam.CustomFactor(noise, [key_a, key_b], partial(_cv_error, cv_transition(t)))
