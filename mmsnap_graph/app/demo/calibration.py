"""The demo's self-calibration of S2 in S1's frame on one run: the closed
form on the nodes' single-target EKF tracks, refined by the joint
calibration graph on their torso centroids (:mod:`mmsnap_graph.app.demo`)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from factors.models import local_to_global

from ...calibration import LocalTracks, MatchingOptions, joint_calibration, match_tracks
from ...data.noise import MeasurementNoise
from ...data.recording import Detections, Recording, Tracks
from ...errors import CalibrationError, ValidationError
from ..commands.calibrate import fact_text
from .chain import (
    DEMO_EKF_MEASUREMENT_STD,
    SingleTrack,
    centroids_near_track,
    single_target_track,
)
from ...evaluation.metrics import PoseError, align_frames, pose_error, pose_mapping_error

#: The joint graph weighs the centroids with the demo EKF's sigmas.
_DEMO_NOISE = MeasurementNoise(range_m=DEMO_EKF_MEASUREMENT_STD[0], omega_rad=DEMO_EKF_MEASUREMENT_STD[1],
                               doppler_mps=DEMO_EKF_MEASUREMENT_STD[2])

__all__ = ["CalibrationOutcome", "track_alignment_rmse", "calibrate_run"]


@dataclass(frozen=True, kw_only=True, slots=True)
class CalibrationOutcome:
    """Self-calibration of S2 in S1's frame on one run.

    closed_form_pose, refined_pose : (3,) ``(x_m, y_m, phi_rad)``; their
    covariances (3, 3) (Pose2 body tangent). closed_form_rmse_m : paper eq. 14
    (the closed form's own track RMSE); refined_rmse_m : the same track RMSE
    with the refined pose. true_pose : (3,). closed_form_error,
    refined_error : :class:`PoseError` against it. closed_form_mapping_error_m,
    refined_mapping_error_m : RMS displacement of the true walking path when
    S2 sees it with the estimated instead of the true pose
    (:func:`mmsnap_graph.evaluation.pose_mapping_error`). n_frames : matched
    frames; lag_frames : the matched frame lag.
    """

    configuration: str
    trajectory: str
    closed_form_pose: NDArray
    closed_form_covariance: NDArray
    closed_form_rmse_m: float
    refined_pose: NDArray
    refined_covariance: NDArray
    refined_rmse_m: float
    true_pose: NDArray
    closed_form_error: PoseError
    refined_error: PoseError
    n_frames: int
    lag_frames: int
    success: bool
    message: str
    closed_form_mapping_error_m: float = float("nan")
    refined_mapping_error_m: float = float("nan")
    track_s1: SingleTrack | None = None
    track_s2: SingleTrack | None = None
    truth_frame: NDArray | None = None
    truth_state: NDArray | None = None

    def to_dict(self) -> dict:
        return {
            "configuration": self.configuration,
            "trajectory": self.trajectory,
            "closed_form_pose": self.closed_form_pose.tolist(),
            "closed_form_covariance": self.closed_form_covariance.tolist(),
            "closed_form_rmse_m": self.closed_form_rmse_m,
            "refined_pose": self.refined_pose.tolist(),
            "refined_covariance": self.refined_covariance.tolist(),
            "refined_rmse_m": self.refined_rmse_m,
            "true_pose": self.true_pose.tolist(),
            "closed_form_error": self.closed_form_error.to_dict(),
            "refined_error": self.refined_error.to_dict(),
            "closed_form_mapping_error_m": self.closed_form_mapping_error_m,
            "refined_mapping_error_m": self.refined_mapping_error_m,
            "n_frames": self.n_frames,
            "lag_frames": self.lag_frames,
            "success": self.success,
            "message": self.message,
        }

    def calibration_json(self, which: str = "refined") -> dict:
        """The project's calibration JSON (S1 reference) for ``which`` pose."""
        pose = self.refined_pose if which == "refined" else self.closed_form_pose
        cov = self.refined_covariance if which == "refined" else self.closed_form_covariance
        return {"reference": "S1", "method": which,
                "nodes": {"S1": {"pose": [0.0, 0.0, 0.0], "covariance": np.zeros((3, 3)).tolist()},
                          "S2": {"pose": pose.tolist(), "covariance": cov.tolist()}}}


def track_alignment_rmse(pose, track_a: SingleTrack, track_b: SingleTrack, lag_frames: int = 0
                         ) -> tuple[float, int]:
    """RMSE of node a's track against node b's track mapped into a's frame by
    ``pose`` (b in a), on their common frames (b's frame ``k + lag`` with a's
    ``k``): paper eq. 14 evaluated at any pose. Returns ``(rmse_m, K)``."""
    _, ia, ib = align_frames(track_a.frame, track_b.frame - int(lag_frames))
    if ia.size == 0:
        return float("nan"), 0
    mapped = local_to_global(track_b.state[ib, :2], np.asarray(pose, dtype=float))
    d = track_a.state[ia, :2] - mapped
    return float(np.sqrt(np.mean(np.sum(d**2, axis=1)))), int(ia.size)


def _run_nodes(recording: Recording) -> tuple[tuple[str, str], tuple[SingleTrack, SingleTrack]]:
    """Validate a two-node run; its node names and single-target tracks."""
    names = recording.node_names
    if len(names) != 2:
        raise ValidationError(f"the demo calibrates two-node networks, got nodes {names}")
    tracks = tuple(single_target_track(recording.nodes[n].tracks
                                       if recording.nodes[n].tracks is not None else Tracks.empty())
                   for n in names)
    return names, tracks


def _refine(recording: Recording, names, tracks, initial_pose: NDArray, lag: int
            ) -> tuple[NDArray, NDArray, bool, str]:
    """The joint calibration graph on the centroids on each node's track
    (S2's frames shifted by the matched lag), started from ``initial_pose``.
    Returns ``(pose, covariance, success, message)``; when the graph raises,
    ``initial_pose`` is kept with ``covariance=None`` and ``success=False``."""
    dets: dict[str, Detections] = {}
    for name, tr in zip(names, tracks):
        d = centroids_near_track(recording.nodes[name].centroids, tr)
        if name == names[1] and lag:
            d = dataclasses.replace(d, frame=d.frame - lag)
        dets[name] = d
    try:
        joint = joint_calibration(dets, initial_poses={names[1]: initial_pose},
                                  noise=_DEMO_NOISE)
    except CalibrationError as exc:
        return initial_pose, None, False, f"refinement failed, closed form kept: {exc}"
    said = "; ".join([joint.status.message, *map(fact_text, joint.facts)])
    return (np.asarray(joint.poses[names[1]], dtype=float),
            np.asarray(joint.covariances[names[1]], dtype=float), bool(joint.success), said)


def _truth_errors(recording: Recording, name: str, cf_pose: NDArray, refined_pose: NDArray
                  ) -> dict:
    """The poses' errors against the true pose of node ``name`` (NaN without
    truth) and the truth's first target, as CalibrationOutcome fields."""
    truth = recording.truth
    true_pose = (np.asarray(truth.node_poses[name], dtype=float)
                 if truth is not None and name in truth.node_poses else np.full(3, np.nan))
    nan_err = PoseError(position_error_m=float("nan"), heading_error_rad=float("nan"))
    has_truth = bool(np.all(np.isfinite(true_pose)))
    t_frame = t_state = None
    map_cf = map_ref = float("nan")
    if truth is not None:
        t_frame, t_state = truth.target(int(truth.target_id.min()))
        if has_truth:
            map_cf = pose_mapping_error(cf_pose, true_pose, t_state[:, :2])
            map_ref = pose_mapping_error(refined_pose, true_pose, t_state[:, :2])
    return dict(
        true_pose=true_pose,
        closed_form_error=pose_error(cf_pose, true_pose) if has_truth else nan_err,
        refined_error=pose_error(refined_pose, true_pose) if has_truth else nan_err,
        closed_form_mapping_error_m=map_cf, refined_mapping_error_m=map_ref,
        truth_frame=t_frame, truth_state=t_state)


def calibrate_run(recording: Recording, *, configuration: str = "?", trajectory: str = "?",
                  max_lag_frames: int = 2) -> CalibrationOutcome:
    """Calibrate S2 in S1's frame from a processed run
    (:func:`mmsnap_graph.app.demo.chain.node_chain`).

    Closed form: :func:`mmsnap_graph.calibration.match_tracks` on each node's
    stitched single-target EKF track (frame-lag search). Refined:
    :func:`mmsnap_graph.calibration.joint_calibration` on the torso centroids
    (one per node and frame, the one on the node's track), started from the
    closed form, with the demo's centroid sigmas
    (:data:`~mmsnap_graph.app.demo.chain.DEMO_EKF_MEASUREMENT_STD`). Raises
    :class:`CalibrationError` when the closed form fails.
    """
    names, tracks = _run_nodes(recording)
    lt = [LocalTracks(frame=t.frame, points_m=t.state[:, :2], track_id=np.zeros(len(t), np.int64))
          for t in tracks]
    period = recording.frame_period_s
    m = match_tracks(lt[0], lt[1], frame_period_s=period,
                     options=MatchingOptions(max_lag_s=max_lag_frames * period))
    if not m.success:
        raise CalibrationError(f"configuration {configuration}, {trajectory}: closed form "
                               f"failed: {m.message}")
    cf = m.calibration
    lag = int(m.lag_frames)
    refined_pose, refined_cov, success, refine_msg = _refine(recording, names, tracks,
                                                            cf.pose, lag)
    if refined_cov is None:
        refined_cov = cf.covariance
    refined_rmse, _ = track_alignment_rmse(refined_pose, tracks[0], tracks[1], lag)
    return CalibrationOutcome(
        configuration=configuration, trajectory=trajectory,
        closed_form_pose=np.asarray(cf.pose, dtype=float),
        closed_form_covariance=np.asarray(cf.covariance, dtype=float),
        closed_form_rmse_m=float(cf.rmse_m), refined_pose=refined_pose,
        refined_covariance=refined_cov, refined_rmse_m=refined_rmse,
        n_frames=int(cf.n_frames), lag_frames=lag, success=success,
        message="; ".join((cf.message, refine_msg)), track_s1=tracks[0], track_s2=tracks[1],
        **_truth_errors(recording, names[1], cf.pose, refined_pose))
