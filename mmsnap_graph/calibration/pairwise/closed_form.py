"""Pairwise self-calibration in closed form (paper eqs. 11-14; docs/CONVENTIONS.md,
"Pairwise self-calibration").

Two nodes see one target at the same frames ``k``; ``z_1[k]`` and ``z_2[k]``
are its positions in each node's local frame, as complex numbers. The pose of
S2 in S1's frame minimizes ``J(p, phi) = sum_k |z_1[k] - p - exp(j phi) z_2[k]|^2``:

.. math::

    \\hat\\phi_{21} = -\\arg(\\hat z_1^H \\hat z_2), \\quad
    \\hat p_{21} = \\bar z_1 - e^{j \\hat\\phi_{21}} \\bar z_2, \\quad
    J_{min} = \\|\\hat z_1\\|^2 + \\|\\hat z_2\\|^2 - 2 |\\hat z_1^H \\hat z_2|.

``(Re p_21, Im p_21, phi_21)`` is ``gtsam.Pose2`` ``S1_T_S2``: a point in S2's
frame maps to S1's frame by ``transformFrom``.

Pose covariance (not in the paper). The residual of frame ``k`` is
``e_k = z_1[k] - T(z_2[k])``. GTSAM perturbs a Pose2 in its body frame,
``T.retract(xi)``, ``xi = (dx_b, dy_b, dphi)``, so

.. math::

    \\partial T(z_2[k]) / \\partial \\xi = R(\\phi) [I_2, \\; J z_2[k]], \\quad
    J = [[0, -1], [1, 0]],

and, with ``A_k`` that matrix, the least-squares estimate has the sandwich
covariance ``H^{-1} (sum_k A_k^T S_k A_k) H^{-1}``, ``H = sum_k A_k^T A_k``,
where ``S_k`` is the covariance of ``e_k``. Two choices of ``S_k``:

- ``"residual"`` (default): isotropic ``S_k = s^2 I`` with
  ``s^2 = J_min / (2K - 3)``, the usual unbiased residual variance; the
  covariance is then ``s^2 H^{-1}``. Exact for isotropic, equal, white noise.
- ``"sandwich"``: ``S_k = e_k e_k^T`` (heteroscedasticity-consistent, HC0),
  which stays consistent when the track noise is anisotropic or varies
  along the track, as radar noise does.
- explicit per-frame ``point_covariances`` ``S_k`` (e.g. ``C_1[k] + R C_2[k]
  R^T`` from two EKFs' position covariances) when you have them.

All three treat frames as independent. EKF tracks are smooth: their errors
are correlated from frame to frame, and the covariance is then too small by
the integrated autocorrelation time ``tau`` of the scores ``A_k^T e_k``
(``K / tau`` is the effective number of frames). ``autocorrelation="auto"``
(default) estimates ``tau`` from the residuals
(:func:`~mmsnap_graph.calibration.pairwise.effective_samples.autocorrelation_factor`) and
multiplies the covariance by it; ``"none"`` keeps the independent-frames
figure.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ...data.calibration import PairwiseCalibration
from ...errors import CalibrationError, ValidationError
from ..._validation import as_float_array, check_finite, check_shape
from .effective_samples import autocorrelation_factor

__all__ = ["closed_form_pose", "closed_form_calibration",
           "alignment_jacobian", "DEFAULT_MIN_COMMON_FRAMES", "DEFAULT_MIN_SPREAD_M"]

#: Fewest common frames a pairwise calibration accepts. Three points fix a
#: pose exactly; a covariance needs a few more residual degrees of freedom.
DEFAULT_MIN_COMMON_FRAMES = 5
#: Smallest RMS spread of a track about its centroid (m) for which the
#: rotation is considered observable; a standing target gives ~ the noise.
DEFAULT_MIN_SPREAD_M = 0.2


def _validate_tracks(z1: ArrayLike, z2: ArrayLike) -> tuple[NDArray, NDArray]:
    a = check_finite(check_shape(as_float_array(z1, "points_a_m"), (None, 2), "points_a_m"),
                     "points_a_m")
    b = check_finite(check_shape(as_float_array(z2, "points_b_m"), (None, 2), "points_b_m"),
                     "points_b_m")
    if a.shape != b.shape:
        raise CalibrationError(f"points_a_m and points_b_m must pair up frame by frame, got "
                               f"shapes {a.shape} and {b.shape}")
    return a, b


def closed_form_pose(points_a_m: NDArray, points_b_m: NDArray) -> tuple[NDArray, float]:
    """The bare closed form, no validation (paper eq. 12, eq. 13).

    points_a_m, points_b_m : (K, 2) float, the same target at the same frames
    in node a's and node b's local frames.
    Returns ``pose (3,)`` of b in a (``a_T_b``) and ``J_min`` (m^2).
    """
    z1 = points_a_m[:, 0] + 1j * points_a_m[:, 1]
    z2 = points_b_m[:, 0] + 1j * points_b_m[:, 1]
    m1 = z1.mean()
    m2 = z2.mean()
    h1 = z1 - m1
    h2 = z2 - m2
    c = np.vdot(h1, h2)  # zhat_1^H zhat_2
    phi = -np.angle(c)
    p = m1 - np.exp(1j * phi) * m2
    j_min = float(np.vdot(h1, h1).real + np.vdot(h2, h2).real - 2.0 * abs(c))
    return np.array([p.real, p.imag, phi]), max(j_min, 0.0)


def alignment_jacobian(pose: ArrayLike, points_b_m: ArrayLike) -> NDArray:
    """Jacobian of ``T(z_b)`` w.r.t. the body-frame tangent of ``T`` (module doc).

    pose : (3,); points_b_m : (K, 2). Returns (K, 2, 3): ``R(phi) [I, J z_b]``.
    """
    pose = np.asarray(pose, dtype=float)
    zb = np.asarray(points_b_m, dtype=float)
    c, s = np.cos(pose[2]), np.sin(pose[2])
    rot = np.array([[c, -s], [s, c]])
    k = zb.shape[0]
    local = np.zeros((k, 2, 3))
    local[:, 0, 0] = 1.0
    local[:, 1, 1] = 1.0
    local[:, 0, 2] = -zb[:, 1]
    local[:, 1, 2] = zb[:, 0]
    return np.einsum("ij,kjl->kil", rot, local)


def _transform(pose: NDArray, pts: NDArray) -> NDArray:
    c, s = np.cos(pose[2]), np.sin(pose[2])
    return np.stack([pose[0] + c * pts[:, 0] - s * pts[:, 1],
                     pose[1] + s * pts[:, 0] + c * pts[:, 1]], axis=-1)


def _symmetrize(m: NDArray) -> NDArray:
    return 0.5 * (m + m.T)


def _check_point_covariances(point_covariances: ArrayLike, k: int) -> NDArray:
    """(K, 2, 2) finite, symmetric, positive semi-definite residual covariances."""
    s_k = check_finite(check_shape(as_float_array(point_covariances, "point_covariances"),
                                   (k, 2, 2), "point_covariances"), "point_covariances")
    if not np.allclose(s_k, np.swapaxes(s_k, -1, -2), rtol=1e-9, atol=0.0):
        raise ValidationError("point_covariances must be symmetric")
    with np.errstate(all="ignore"):
        eig = np.linalg.eigvalsh(s_k)
    bad = np.flatnonzero(eig[:, 0] < -1e-12 * np.maximum(np.abs(eig[:, 1]), 1e-300))
    if bad.size:
        raise ValidationError(f"point_covariances must be positive semi-definite; "
                              f"point_covariances[{bad[0]}] has eigenvalues {eig[bad[0]]}")
    return s_k


def _scale_of(a: NDArray, b: NDArray) -> float:
    """A length (m) the tracks are divided by before the arithmetic, so that
    coordinates of 1e-300 m or 1e300 m neither underflow nor overflow when
    squared. A power of two: the division is exact."""
    biggest = float(max(np.abs(a).max(), np.abs(b).max()))
    if biggest == 0.0:
        return 1.0
    return float(2.0 ** np.frexp(biggest)[1])


def _unit_covariance(covariance: str, s_k: NDArray | None, pose: NDArray, a: NDArray,
                     b: NDArray, j_min: float) -> NDArray:
    """Pose covariance in the scaled units (module docstring), plus the
    variance of rounding (relative 64 eps per coordinate), so that tracks
    that fit exactly get a tiny positive-definite covariance, not zero."""
    k = a.shape[0]
    # H = sum_k A_k^T A_k with A_k = R [I, J z_b]; R^T R = I, so H depends on
    # the b-track only: [[K I, J sum z_b], [(J sum z_b)^T, sum |z_b|^2]].
    sb = b.sum(axis=0)
    h = np.empty((3, 3))
    h[:2, :2] = np.eye(2) * k
    h[:2, 2] = h[2, :2] = np.array([-sb[1], sb[0]])
    h[2, 2] = float((b * b).sum())
    h_inv = np.linalg.inv(h)  # 3x3, well conditioned once the spread check passed
    if s_k is not None:
        jac = alignment_jacobian(pose, b)  # (K, 2, 3)
        cov = h_inv @ np.einsum("kia,kij,kjb->ab", jac, s_k, jac) @ h_inv
    elif covariance == "residual":
        cov = (j_min / max(2 * k - 3, 1)) * h_inv
    else:  # sandwich
        g = _scores(pose, a, b)
        cov = h_inv @ (g.T @ g) @ h_inv
    rounding = (64.0 * np.finfo(float).eps) ** 2  # coordinates are at most 1 here
    return _symmetrize(cov + rounding * h_inv)


def _scores(pose: NDArray, a: NDArray, b: NDArray) -> NDArray:
    """(K, 3) per-frame scores ``A_k^T e_k`` (module docstring):
    ``u = R^T e``, then ``(u, (J z_b) . u)``."""
    e = a - _transform(pose, b)
    c, s = np.cos(pose[2]), np.sin(pose[2])
    ux = c * e[:, 0] + s * e[:, 1]
    uy = -s * e[:, 0] + c * e[:, 1]
    return np.column_stack([ux, uy, b[:, 0] * uy - b[:, 1] * ux])


def _sound(pose: NDArray, cov: NDArray, j_min: float) -> str:
    """Why the result cannot be a success ('' if it can): success=True means
    finite numbers and a positive-definite covariance."""
    if not (np.isfinite(pose).all() and np.isfinite(cov).all() and np.isfinite(j_min)):
        return "the pose, its covariance or the cost is not finite at this scale"
    if np.linalg.eigvalsh(cov).min() <= 0.0:
        return "the pose covariance is not positive definite at this scale"
    return ""


def closed_form_calibration(
    points_a_m: ArrayLike,
    points_b_m: ArrayLike,
    *,
    covariance: Literal["residual", "sandwich"] = "residual",
    point_covariances: ArrayLike | None = None,
    min_common_frames: int = DEFAULT_MIN_COMMON_FRAMES,
    min_spread_m: float = DEFAULT_MIN_SPREAD_M,
    frames: ArrayLike | None = None,
    autocorrelation: Literal["auto", "none"] = "auto",
) -> PairwiseCalibration:
    """Pose of node b in node a's frame from one target's matched local tracks.

    Parameters
    ----------
    points_a_m, points_b_m : (K, 2) float
        The target's position at the same K frames in each node's local frame
        (EKF tracks, or detections mapped with ``factors.detection_to_local``).
    covariance : "residual" or "sandwich"
        How the pose covariance is derived (module docstring); ignored when
        ``point_covariances`` is given.
    point_covariances : (K, 2, 2) float, optional
        Covariance of each frame's alignment residual ``z_a - T(z_b)``
        (symmetric positive semi-definite, else :class:`ValidationError`).
    min_common_frames : int
        Fewer frames raise :class:`CalibrationError`.
    min_spread_m : float
        A track whose RMS distance to its centroid is below this in either
        node (a standing target; or exactly zero) raises
        :class:`CalibrationError`: the rotation is unobservable.
    frames : (K,) int, optional
        Frame numbers, stored in the result; they order the residuals in
        time for the autocorrelation (default: consecutive frames).
    autocorrelation : "auto" or "none"
        ``"auto"``: the covariance is multiplied by the integrated
        autocorrelation time of the residual scores (module docstring);
        ``"none"``: frames are independent (white track noise).

    Returns
    -------
    PairwiseCalibration
        The arithmetic runs on tracks divided by a power of two, so any
        finite coordinates work. Tracks that fit exactly get the covariance
        of rounding (tiny, positive definite). ``success=False`` (with the
        reason in ``message``) when the covariance cannot be represented
        (coordinates near the float limits); ``success=True`` implies a
        finite pose and a positive-definite covariance.
    """
    if covariance not in ("residual", "sandwich"):
        raise ValidationError(f"covariance={covariance!r} must be 'residual' or 'sandwich'")
    if autocorrelation not in ("auto", "none"):
        raise ValidationError(f"autocorrelation={autocorrelation!r} must be 'auto' or 'none'")
    try:
        bad = isinstance(min_common_frames, bool) or not (float(min_common_frames) >= 0
                                                          and np.isfinite(min_common_frames))
    except (TypeError, ValueError):
        bad = True
    if bad:
        raise ValidationError(f"min_common_frames must be a finite count >= 0, got "
                              f"{min_common_frames!r}")
    a, b = _validate_tracks(points_a_m, points_b_m)
    k = a.shape[0]
    if k < max(int(min_common_frames), 3):
        raise CalibrationError(f"too few common frames for a pairwise calibration: "
                               f"{k} < min_common_frames={max(int(min_common_frames), 3)}")
    scale = _scale_of(a, b)
    ua, ub = a / scale, b / scale
    spread_a = float(np.sqrt(((ua - ua.mean(0)) ** 2).sum(axis=1).mean()))
    spread_b = float(np.sqrt(((ub - ub.mean(0)) ** 2).sum(axis=1).mean()))
    if min(spread_a, spread_b) * scale < min_spread_m or min(spread_a, spread_b) <= 1e-12:
        raise CalibrationError(
            f"the target hardly moves (track spread {spread_a * scale:.3g} m in a, "
            f"{spread_b * scale:.3g} m in b, below min_spread_m={min_spread_m} or zero): "
            "the relative rotation is unobservable")
    s_k = None
    if point_covariances is not None:
        s_k = _check_point_covariances(point_covariances, k) / scale / scale
    unit_pose, unit_j = closed_form_pose(ua, ub)
    unit_cov = _unit_covariance(covariance, s_k, unit_pose, ua, ub, unit_j)
    fr = None if frames is None else np.asarray(frames, dtype=np.int64)
    if fr is not None and fr.shape != (k,):
        raise ValidationError(f"frames must have shape ({k},) like the points, got {fr.shape}")
    tau = 1.0
    if autocorrelation == "auto":
        tau = autocorrelation_factor(_scores(unit_pose, ua, ub),
                                     np.arange(k) if fr is None else fr)
        unit_cov = unit_cov * tau
    d = np.array([scale, scale, 1.0])
    with np.errstate(over="ignore", under="ignore"):
        pose = unit_pose * d
        cov = _symmetrize(unit_cov * np.outer(d, d))
        j_min = unit_j * scale * scale
        rmse = float(np.sqrt(unit_j / k) * scale)
    why = _sound(pose, cov, j_min)
    note = f", residuals correlated: covariance x {tau:.3g}" if tau > 1.05 else ""
    return PairwiseCalibration(
        pose=pose, covariance=cov, cost_m2=j_min, rmse_m=rmse, n_frames=k, frames=fr,
        success=not why, points_a_m=a, points_b_m=b, autocorrelation_factor=tau,
        message=why or f"closed form on {k} frames, track RMSE {rmse:.3g} m{note}")
