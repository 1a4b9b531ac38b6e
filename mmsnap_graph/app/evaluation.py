"""Metrics for fused estimates, tracks and calibrated poses.

Pure functions on arrays: RMSE of states against a reference on common frames
(paper Tables II and III), pose errors, and the normalized estimation error
squared (NEES) that checks a covariance is honest.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from factors.models import global_to_local, local_to_global, wrap_angle

from .._validation import as_float_array
from ..errors import ValidationError
from ..tracking.track_fusion import transform_tracks

__all__ = [
    "StateErrors",
    "PoseError",
    "align_frames",
    "state_errors",
    "pose_error",
    "pose_mapping_error",
    "truth_reference",
    "evaluate_recording",
    "failed_checks",
    "nees",
    "chi2_mean_interval",
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


# ----------------------------------------------------------------------------
# A whole recording (``mmsnap evaluate``)
# ----------------------------------------------------------------------------


def _nees_summary(err: NDArray, cov: NDArray) -> dict:
    ok = np.all(np.isfinite(err), axis=1) & np.all(np.isfinite(cov), axis=(1, 2))
    rows = np.flatnonzero(ok)
    good = []
    for i in rows:
        try:
            np.linalg.cholesky(cov[i])
            good.append(i)
        except np.linalg.LinAlgError:
            continue
    if not good:
        return {"mean": float("nan"), "n": 0, "interval_95": [float("nan"), float("nan")],
                "passed": None}
    good = np.asarray(good)
    values = nees(err[good], cov[good])
    lo, hi = chi2_mean_interval(err.shape[1], good.size)
    mean = float(np.mean(values))
    return {"mean": mean, "n": int(good.size), "interval_95": [lo, hi],
            "passed": bool(lo <= mean <= hi)}


def failed_checks(metrics: dict) -> list[str]:
    """The consistency checks of :func:`evaluate_recording`'s ``metrics``
    that failed, one sentence each (empty when all passed or none ran): the
    fused rows' mean NEES outside its 95% chi-square interval (the
    covariances are too small or too large for the errors)."""
    out = []
    fu = metrics.get("fused")
    if fu is not None and fu["nees"].get("passed") is False:
        nz = fu["nees"]
        lo, hi = nz["interval_95"]
        side = "over-confident: covariances too small" if nz["mean"] > hi else \
            "under-confident: covariances too large"
        out.append(f"NEES check failed for the fused states: mean NEES {nz['mean']:.2f} over "
                   f"{nz['n']} rows is outside the 95% interval ({lo:.2f}, {hi:.2f}) ({side})")
    return out


def _degeneracy_threshold() -> float:
    # Imported here: GTSAM (fusion.solvers.gtsam_graph) stays off this module's path,
    # pure functions on arrays. The threshold moves to a GTSAM-free module
    # with the fusion redesign; then this import goes to the module level.
    from ..fusion.solvers.gtsam_graph import DEGENERACY_THRESHOLD

    return float(DEGENERACY_THRESHOLD)


def evaluate_recording(recording, *, fused=None, node_poses=None) -> dict:
    """Metrics of a recording with truth, as a JSON-ready dict.

    recording : :class:`mmsnap_graph.data.recording.Recording` with ``truth``.
    fused : :class:`mmsnap_graph.fusion.recording.sequence.FusedSequence` (the ``/fused``
        group) or None. Each successful fused row is compared with the true
        state of the nearest target in its frame (:func:`truth_reference`):
        position and velocity RMSE (all rows, and the rows every node
        observed: false-alarm groups seen by one node drop out), and the NEES
        of its covariance.
    node_poses : name -> (3,) calibrated poses (e.g. a calibration JSON);
        default the poses stored on the nodes. Compared with the true poses
        (:func:`pose_error`, :func:`pose_mapping_error` over the true paths)
        and used to move each node's tracks into the global frame, which are
        then compared with the truth like the fused rows.
    A truth with surveyed node poses but no trajectory (no rows) scores the
    poses alone: ``path_error_m`` is None, ``fused`` and every track None,
    with a note.
    Returns ``{"fused": ..., "tracks": {node: ...}, "poses": {node: ...},
    "notes": [...], "failed_checks": [...]}``; a part that cannot be
    evaluated is None with a note; ``failed_checks`` is
    :func:`failed_checks` (``fused["nees"]["passed"]`` holds the NEES check).
    """
    truth = recording.truth
    if truth is None:
        raise ValidationError("the recording has no truth: nothing to evaluate against")
    notes: list[str] = []
    out: dict = {"n_truth_rows": int(truth.frame.size),
                 "n_targets": int(np.unique(truth.target_id).size)}
    given = {} if node_poses is None else {str(k): np.asarray(v, dtype=float)
                                           for k, v in node_poses.items()}
    poses = {name: given.get(name, node.pose) for name, node in recording.nodes.items()}
    out["poses"] = _evaluate_poses(poses, truth, notes)
    if truth.frame.size == 0:
        notes.append("the truth has no trajectory (surveyed poses only): fused states and "
                     "tracks are not scored")
        out["fused"] = None
        out["tracks"] = {name: None for name in recording.nodes}
    else:
        out["fused"] = _evaluate_fused(fused, truth, notes)
        out["tracks"] = _evaluate_tracks(recording, poses, truth, notes)
    out["notes"] = notes
    out["failed_checks"] = failed_checks(out)
    return out


def _evaluate_poses(poses: dict, truth, notes: list[str]) -> dict:
    """Each node's calibrated pose against its true pose (None with a note
    when either is missing)."""
    path = truth.state[:, :2]
    pose_rows = {}
    for name, pose in poses.items():
        true = truth.node_poses.get(name)
        if pose is None:
            notes.append(f"node {name}: no calibrated pose")
            pose_rows[name] = None
            continue
        if true is None:
            notes.append(f"node {name}: no true pose in the truth")
            pose_rows[name] = None
            continue
        pe = pose_error(pose, true)
        pose_rows[name] = {"pose": np.asarray(pose, float).tolist(),
                           "true_pose": np.asarray(true, float).tolist(),
                           "position_error_m": pe.position_error_m,
                           "heading_error_rad": pe.heading_error_rad,
                           # Over the true walking path; none without a trajectory.
                           "path_error_m": pose_mapping_error(pose, true, path)
                           if path.shape[0] else None}
    return pose_rows


def _evaluate_fused(fused, truth, notes: list[str]) -> dict | None:
    """The successful fused rows against the nearest true target."""
    if fused is None:
        notes.append("no /fused group: run `mmsnap fuse` to evaluate one-shot estimates")
        return None
    ok = np.asarray(fused.success, dtype=bool)
    ref, _ = truth_reference(fused.frame[ok], fused.state[ok, :2], truth.frame, truth.target_id,
                             truth.state)
    err = fused.state[ok] - ref
    se = state_errors(fused.state[ok], ref)
    deg = np.asarray(fused.degeneracy)[ok]
    every = np.asarray(fused.observed, dtype=bool)[ok].all(axis=1)
    return {"mode": str(fused.mode), "covariance_method": str(fused.covariance_method),
            "n_rows": int(len(fused)), "n_success": int(ok.sum()),
            **se.to_dict(),
            "observed_by_all_nodes": state_errors(fused.state[ok][every], ref[every]).to_dict(),
            "nees": _nees_summary(err, np.asarray(fused.covariance)[ok]),
            "degenerate_fraction": float(np.mean(deg > _degeneracy_threshold()))
            if deg.size else float("nan")}


def _evaluate_tracks(recording, poses: dict, truth, notes: list[str]) -> dict:
    """Each node's tracks, moved into the global frame with its pose
    (:func:`mmsnap_graph.tracking.track_fusion.transform_tracks`), against
    the nearest true target."""
    tracks_out = {}
    for name, node in recording.nodes.items():
        if node.tracks is None or len(node.tracks) == 0:
            tracks_out[name] = None
            continue
        pose = poses[name]
        if pose is None:
            tracks_out[name] = None
            notes.append(f"node {name}: tracks not evaluated (no pose to place them)")
            continue
        glob, _ = transform_tracks(node.tracks.state, node.tracks.covariance, pose)
        ref, _ = truth_reference(node.tracks.frame, glob[:, :2], truth.frame, truth.target_id,
                                 truth.state)
        tracks_out[name] = {"n_rows": int(len(node.tracks)),
                            "n_tracks": int(node.tracks.track_ids.size),
                            **state_errors(glob, ref).to_dict()}
    return tracks_out
