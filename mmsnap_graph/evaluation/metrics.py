"""Metrics for fused estimates, tracks and calibrated poses.

Pure functions on arrays: RMSE of states against a reference on common frames
(paper Tables II and III), pose errors, and the normalized estimation error
squared (NEES) that checks a covariance is honest. Below the estimators, so
their tests and the application share one definition of each metric.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from factors.models import global_to_local, local_to_global, wrap_angle

from .._validation import as_float_array
from ..errors import ValidationError

__all__ = [
    "StateErrors",
    "PoseError",
    "align_frames",
    "state_errors",
    "pose_error",
    "pose_mapping_error",
    "truth_reference",
    "nees",
    "chi2_mean_interval",
    "NeesCheck",
    "nees_check",
]


@dataclass(frozen=True, kw_only=True, slots=True)
class StateErrors:
    """RMSE of position and velocity estimates against a reference.

    position_rmse_m : sqrt(mean |p_est - p_ref|^2) over the compared frames.
    velocity_rmse_mps : the same for velocity.
    n_frames : how many frames were compared (both finite).
    """

    position_rmse_m: float
    velocity_rmse_mps: float
    n_frames: int

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True, kw_only=True, slots=True)
class PoseError:
    """Error of an estimated node pose against the true one.

    position_error_m : |p_est - p_true|; heading_error_rad : wrapped phi error.
    """

    position_error_m: float
    heading_error_rad: float

    def to_dict(self) -> dict:
        return asdict(self)


def align_frames(
    frames_a: ArrayLike, frames_b: ArrayLike
) -> tuple[NDArray, NDArray, NDArray]:
    """Common frames of two frame lists: ``(frames, index_a, index_b)``.

    Each frame must appear at most once in each list.
    """
    fa = np.asarray(frames_a, dtype=np.int64)
    fb = np.asarray(frames_b, dtype=np.int64)
    for name, f in (("frames_a", fa), ("frames_b", fb)):
        if f.ndim != 1:
            raise ValidationError(f"{name} must be 1-D, got shape {f.shape}")
        if np.unique(f).size != f.size:
            raise ValidationError(f"{name} has repeated frames; select one target first")
    common, ia, ib = np.intersect1d(fa, fb, assume_unique=True, return_indices=True)
    return common, ia, ib


def state_errors(estimate: ArrayLike, reference: ArrayLike) -> StateErrors:
    """RMSE of ``estimate (K, 4)`` against ``reference (K, 4)``, both
    ``(x_m, y_m, vx_mps, vy_mps)`` on the same frames; rows with a non-finite
    value in either are skipped (e.g. failed frames)."""
    est = as_float_array(estimate, "estimate")
    ref = as_float_array(reference, "reference")
    if est.ndim != 2 or est.shape[1] != 4 or est.shape != ref.shape:
        raise ValidationError(
            f"estimate and reference must both have shape (K, 4), got {est.shape} and {ref.shape}"
        )
    ok = np.all(np.isfinite(est), axis=1) & np.all(np.isfinite(ref), axis=1)
    n = int(ok.sum())
    if n == 0:
        return StateErrors(position_rmse_m=float("nan"), velocity_rmse_mps=float("nan"), n_frames=0)
    d = est[ok] - ref[ok]
    return StateErrors(
        position_rmse_m=float(np.sqrt(np.mean(np.sum(d[:, :2] ** 2, axis=1)))),
        velocity_rmse_mps=float(np.sqrt(np.mean(np.sum(d[:, 2:] ** 2, axis=1)))),
        n_frames=n,
    )


def pose_error(estimate: ArrayLike, truth: ArrayLike) -> PoseError:
    """Error of an estimated pose ``(x_m, y_m, phi_rad)`` against the truth."""
    est = as_float_array(estimate, "estimate")
    tru = as_float_array(truth, "truth")
    if est.shape != (3,) or tru.shape != (3,):
        raise ValidationError(f"poses must have shape (3,), got {est.shape} and {tru.shape}")
    return PoseError(
        position_error_m=float(np.hypot(*(est[:2] - tru[:2]))),
        heading_error_rad=float(wrap_angle(est[2] - tru[2])),
    )


def pose_mapping_error(estimate: ArrayLike, truth: ArrayLike, points_m: ArrayLike) -> float:
    """RMS displacement of global points ``(K, 2)`` seen by a node of pose
    ``truth`` and placed with the pose ``estimate`` (both ``(x_m, y_m,
    phi_rad)``): ``p -> T_est T_true^-1 p``.

    One number for a pose error where it matters, e.g. over the walking
    area: the heading error weighs with the distance of the points from the
    node, the position error adds everywhere.
    """
    est = as_float_array(estimate, "estimate")
    tru = as_float_array(truth, "truth")
    pts = as_float_array(points_m, "points_m")
    if est.shape != (3,) or tru.shape != (3,):
        raise ValidationError(f"poses must have shape (3,), got {est.shape} and {tru.shape}")
    if pts.ndim != 2 or pts.shape[1] != 2 or pts.shape[0] == 0:
        raise ValidationError(f"points_m must have shape (K, 2) with K >= 1, got {pts.shape}")
    moved = local_to_global(global_to_local(pts, tru), est)
    return float(np.sqrt(np.mean(np.sum((moved - pts) ** 2, axis=1))))


def truth_reference(frames: ArrayLike, positions_m: ArrayLike, truth_frame: ArrayLike,
                    truth_target: ArrayLike, truth_state: ArrayLike) -> tuple[NDArray, NDArray]:
    """The true state each estimate refers to: for every row (frame, global
    position ``(K, 2)``), the truth row of the same frame whose target is the
    nearest. Returns ``states (K, 4)`` (NaN where the frame has no truth) and
    ``target_id (K,)`` (-1 there).

    truth_frame, truth_target : (T,) int; truth_state : (T, 4).
    """
    fr = np.asarray(frames, dtype=np.int64)
    pos = as_float_array(positions_m, "positions_m")
    tf = np.asarray(truth_frame, dtype=np.int64)
    tt = np.asarray(truth_target, dtype=np.int64)
    ts = as_float_array(truth_state, "truth_state")
    if fr.ndim != 1 or pos.shape != (fr.size, 2):
        raise ValidationError(f"frames (K,) and positions_m (K, 2) disagree: {fr.shape}, {pos.shape}")
    if tf.ndim != 1 or tt.shape != tf.shape or ts.shape != (tf.size, 4):
        raise ValidationError(f"truth_frame (T,), truth_target (T,) and truth_state (T, 4) "
                              f"disagree: {tf.shape}, {tt.shape}, {ts.shape}")
    out = np.full((fr.size, 4), np.nan)
    tid = np.full(fr.size, -1, dtype=np.int64)
    order = np.argsort(tf, kind="stable")
    tf_s = tf[order]
    lo = np.searchsorted(tf_s, fr, side="left")
    hi = np.searchsorted(tf_s, fr, side="right")
    for i in np.flatnonzero(hi > lo):
        rows = order[lo[i]:hi[i]]
        d = np.sum((ts[rows, :2] - pos[i]) ** 2, axis=1)
        j = rows[int(np.argmin(np.where(np.isfinite(d), d, np.inf)))]
        out[i] = ts[j]
        tid[i] = tt[j]
    return out, tid


def nees(errors: ArrayLike, covariances: ArrayLike) -> NDArray:
    """Normalized estimation error squared ``e^T P^-1 e`` per row.

    errors : (K, D); covariances : (K, D, D), symmetric positive definite.
    Solved by Cholesky (no explicit inverse). Returns (K,).
    """
    e = as_float_array(errors, "errors")
    p = as_float_array(covariances, "covariances")
    if e.ndim != 2 or p.shape != e.shape + (e.shape[1],):
        raise ValidationError(
            f"errors (K, D) and covariances (K, D, D) disagree: {e.shape} and {p.shape}"
        )
    chol = np.linalg.cholesky(p)
    w = np.linalg.solve(chol, e[..., None])[..., 0]
    return np.sum(w**2, axis=-1)


def chi2_mean_interval(dof: int, n: int, confidence: float = 0.95) -> tuple[float, float]:
    """Two-sided interval of the mean of ``n`` independent chi-square(dof)
    variables: ``n * mean ~ chi2(n * dof)``."""
    from scipy.stats import chi2

    a = (1.0 - confidence) / 2.0
    return (float(chi2.ppf(a, n * dof) / n), float(chi2.ppf(1.0 - a, n * dof) / n))


@dataclass(frozen=True, kw_only=True, slots=True)
class NeesCheck:
    """The mean NEES of a set of estimates against its chi-square interval.

    mean : mean NEES over the ``n`` rows used; interval : the two-sided
    interval of that mean at ``confidence`` (:func:`chi2_mean_interval`);
    passed : the mean lies inside it (None when no row could be used).
    """

    mean: float
    n: int
    interval: tuple[float, float]
    passed: bool | None

    def to_dict(self) -> dict:
        return asdict(self)


def nees_check(errors: ArrayLike, covariances: ArrayLike, *, confidence: float = 0.95) -> NeesCheck:
    """Is the mean NEES of ``errors (K, D)`` under ``covariances (K, D, D)``
    inside its chi-square interval? Rows with a non-finite value or a
    covariance that is not positive definite are left out (a failed or
    degenerate estimate carries no covariance to check)."""
    e = as_float_array(errors, "errors")
    p = as_float_array(covariances, "covariances")
    if e.ndim != 2 or p.shape != e.shape + (e.shape[1],):
        raise ValidationError(
            f"errors (K, D) and covariances (K, D, D) disagree: {e.shape} and {p.shape}"
        )
    ok = np.all(np.isfinite(e), axis=1) & np.all(np.isfinite(p), axis=(1, 2))
    good = []
    for i in np.flatnonzero(ok):
        try:
            np.linalg.cholesky(p[i])
        except np.linalg.LinAlgError:
            continue
        good.append(i)
    if not good:
        return NeesCheck(mean=float("nan"), n=0, interval=(float("nan"), float("nan")),
                         passed=None)
    rows = np.asarray(good)
    mean = float(np.mean(nees(e[rows], p[rows])))
    lo, hi = chi2_mean_interval(e.shape[1], rows.size, confidence)
    return NeesCheck(mean=mean, n=int(rows.size), interval=(lo, hi), passed=bool(lo <= mean <= hi))
