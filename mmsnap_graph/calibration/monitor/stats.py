"""The statistics of the decalibration monitor (:mod:`.decalibration`;
docs/CALIBRATION.md, "Noticing a moved radar").

Node ``i`` is checked against the target state fused from the *other* nodes
(leave-one-node-out), so its own measurements cannot absorb its error. With
that state ``x`` (covariance ``P``), node ``i``'s range and spatial frequency
give the innovation ``e = z_i - h_i(x; pose_i)`` (2-vector, spatial frequency
wrapped) of covariance ``S = J P J^T + R`` (``J = dh_i/dx``, ``R`` the
measurement noise). A small error ``delta`` of the pose (GTSAM body tangent
``(dx_b, dy_b, dphi)``, docs/CONVENTIONS.md) adds ``H delta`` to ``e``
(``H = dh_i/dpose``, :func:`factors.models.measurement_model_pose`). Each
frame therefore contributes the information ``A = H^T S^-1 H`` and the score
``b = H^T S^-1 e`` about ``delta``; a window's sums ``A_w``, ``b_w`` estimate
the pose error in that window. A bump is a persistent ``delta``; noise is not.

Change test of a window against the reference (every earlier frame since the
last reset, with the calibration covariance ``C0`` as prior): with
``u = b_w - A_w delta_ref`` and the noise scale ``s^2`` (the mean normalized
innovation squared per degree of freedom),

.. math:: T = u^T (s^2 A_w + A_w C_{ref} A_w)^{+} u \\sim \\chi^2_3

under "no change". Doppler is left out: its pose sensitivity is small and the
leave-one-out velocity rests on the prior when one other node is left.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from factors.models import measurement_model_pose, wrap_angle

from ...data.noise import MeasurementNoise

__all__ = ["HUBER_K", "FrameContributions", "frame_contributions", "compose_pose", "window_statistic",
           "suffix_statistics", "recalibrate_pose", "PoseFit"]

#: Huber constant on a frame's whitened innovation norm (2 degrees of freedom:
#: ``chi2.sf(3**2, 2) = 1.1%`` of clean frames are down-weighted).
HUBER_K = 3.0
#: Relative eigenvalue cut of the pseudo-inverse of a window's information.
_RCOND = 1e-9


@dataclass(frozen=True, slots=True)
class FrameContributions:
    """Per-frame information ``a (F, 3, 3)``, score ``b (F, 3)`` about the pose
    error, and normalized innovation squared ``nis (F,)`` (2 degrees of freedom)."""

    a: NDArray
    b: NDArray
    nis: NDArray


def frame_contributions(pose: NDArray, states: NDArray, state_covariances: NDArray,
                        measurements: NDArray, noise: MeasurementNoise, *,
                        huber_k: float | None = HUBER_K) -> FrameContributions:
    """Contributions of ``F`` frames of one node (module doc); with
    ``huber_k`` a frame whose whitened innovation norm ``sqrt(nis)`` exceeds
    it is down-weighted by ``huber_k / sqrt(nis)`` (Huber), so that one wild
    detection cannot make a change.

    pose : (3,) the node's assumed pose; states, state_covariances : (F, 4),
    (F, 4, 4) the leave-one-out fused states; measurements : (F, 3) the node's
    ``(range_m, omega_rad, doppler_mps)``.
    """
    h, j_pose, j_state = measurement_model_pose(np.broadcast_to(pose, (states.shape[0], 3)),
                                                states)
    e = measurements[:, :2] - h[:, :2]
    e[:, 1] = wrap_angle(e[:, 1])
    js = j_state[:, :2, :]
    s = js @ state_covariances @ np.swapaxes(js, 1, 2)
    s[:, 0, 0] += noise.range_m ** 2
    s[:, 1, 1] += noise.omega_rad ** 2
    w = np.linalg.inv(s)
    hp = j_pose[:, :2, :]
    hw = np.swapaxes(hp, 1, 2) @ w
    nis = np.einsum("fi,fij,fj->f", e, w, e)
    weight = np.ones_like(nis)
    if huber_k is not None:
        norm = np.sqrt(nis)
        big = norm > huber_k
        weight[big] = huber_k / norm[big]
    a = (hw @ hp) * weight[:, None, None]
    b = np.einsum("fij,fj->fi", hw, e) * weight[:, None]
    return FrameContributions(a=a, b=b, nis=nis)


def compose_pose(pose: NDArray, delta: NDArray) -> NDArray:
    """``pose`` moved by ``delta`` in its body frame: ``Pose2(pose) * Pose2(delta)``."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    return np.array([pose[0] + c * delta[0] - s * delta[1],
                     pose[1] + s * delta[0] + c * delta[1],
                     (pose[2] + delta[2] + np.pi) % (2 * np.pi) - np.pi])


def _statistic(a_w: NDArray, b_w: NDArray, delta_ref: NDArray, cov_ref: NDArray,
               scale: float) -> NDArray:
    """``T`` of windows with sums ``a_w (..., 3, 3)``, ``b_w (..., 3)``."""
    u = b_w - np.einsum("...ij,j->...i", a_w, delta_ref)
    m = scale * a_w + a_w @ cov_ref @ a_w
    m = 0.5 * (m + np.swapaxes(m, -1, -2))
    top = np.max(np.abs(np.linalg.eigvalsh(m)), axis=-1)
    mp = np.linalg.pinv(m, rcond=_RCOND, hermitian=True)
    t = np.einsum("...i,...ij,...j->...", u, mp, u)
    return np.where(top > 0, t, 0.0)


def window_statistic(a: NDArray, b: NDArray, lengths: NDArray, delta_ref: NDArray,
                     cov_ref: NDArray, scale: float) -> NDArray:
    """``T`` of the windows made of the last ``lengths`` frames of ``a (M, 3, 3)``,
    ``b (M, 3)`` (a length over ``M`` is cut to ``M``)."""
    m = a.shape[0]
    ca = np.cumsum(a[::-1], axis=0)
    cb = np.cumsum(b[::-1], axis=0)
    idx = np.minimum(np.asarray(lengths), m) - 1
    return _statistic(ca[idx], cb[idx], delta_ref, cov_ref, scale)


def suffix_statistics(a: NDArray, b: NDArray, delta_ref: NDArray, cov_ref: NDArray,
                      scale: float) -> NDArray:
    """``T`` of every window ending at the last frame: element ``k`` is the
    window starting at frame ``k`` (the change-time estimate is its argmax)."""
    lengths = np.arange(a.shape[0], 0, -1)
    return window_statistic(a, b, lengths, delta_ref, cov_ref, scale)


@dataclass(frozen=True, slots=True)
class PoseFit:
    """A node's pose re-estimated against the other nodes' fused states.

    pose : (3,); covariance : (3, 3) in the body tangent at ``pose``, scaled by
    the noise scale; iterations; success; message."""

    pose: NDArray
    covariance: NDArray
    iterations: int
    success: bool
    message: str


def recalibrate_pose(pose: NDArray, states: NDArray, state_covariances: NDArray,
                     measurements: NDArray, noise: MeasurementNoise, *, scale: float = 1.0,
                     max_iterations: int = 20, tolerance: float = 1e-9) -> PoseFit:
    """Gauss-Newton on the node's pose: each step solves ``A delta = b`` (the
    window's sums of :func:`frame_contributions` at the current pose) and moves
    the pose by ``delta``; the covariance is ``scale * A^-1`` at the solution.
    Never raises on a singular window: ``success=False`` with the reason."""
    current = np.asarray(pose, dtype=float).copy()
    for it in range(1, max_iterations + 1):
        fc = frame_contributions(current, states, state_covariances, measurements, noise,
                                 huber_k=None)
        a, b = fc.a.sum(axis=0), fc.b.sum(axis=0)
        eig = np.linalg.eigvalsh(a)
        if not np.all(np.isfinite(eig)) or eig[0] <= 1e-9 * max(eig[-1], 1e-300):
            return PoseFit(pose=current, covariance=np.full((3, 3), np.nan), iterations=it,
                           success=False, message="the window does not observe every pose "
                                                  "direction (a target that hardly moves?)")
        delta = np.linalg.solve(a, b)
        current = compose_pose(current, delta)
        if np.all(np.abs(delta) < tolerance * (1.0 + np.abs(current))):
            break
    fc = frame_contributions(current, states, state_covariances, measurements, noise,
                             huber_k=None)
    cov = scale * np.linalg.inv(fc.a.sum(axis=0))
    return PoseFit(pose=current, covariance=0.5 * (cov + cov.T), iterations=it, success=True,
                   message=f"Gauss-Newton on {states.shape[0]} frames")
