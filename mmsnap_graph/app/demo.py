"""The end-to-end demo: the paper's experiments on simulated data (``mmsnap demo``).

For each configuration (A, B, C) and each trajectory (straight, random) a
recording of one walking person is simulated, and the paper's protocol is
followed: **calibrate on one trajectory, fuse the other** (the calibration of
the straight run is used to fuse the random run and vice versa).

Levels (stated in every output):

- **raw-cube stretch** (:func:`run_cube_stretch`): a short recording with raw
  ADC cubes goes through the whole per-node chain (range/Doppler/angle FFTs,
  OS-CFAR, torso DBSCAN, EKF) and is fused with the true poses, to show the
  chain end to end; synthesizing and processing 6 runs x 2 nodes x 600 frames
  of cubes would not fit the demo's time budget;
- **the six configuration x trajectory runs** (:func:`run_configuration`)
  start from the simulator's point clouds (its statistical model of the FFT +
  CFAR output, limbs and false alarms included): torso DBSCAN -> per-node EKF
  -> self-calibration (closed form on the EKF tracks, then the joint
  calibration graph, "refined") -> one-shot fusion (Bayesian MAP and ML) with
  the refined poses -> track-level fusion (covariance intersection of the two
  EKF tracks, the paper's benchmark) and the central tracker.

Metrics follow the paper: Table II is the calibration track RMSE (paper eq.
14) per configuration and calibration trajectory; Table III the one-shot
position and velocity RMSE (Bayesian and ML) per configuration and fused
trajectory, against the track-level fusion (as the paper) and against the
ground truth (which the paper did not have), on the frames common to all.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from typing import Callable, Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from factors.models import local_to_global, measurement_model

from ..errors import CalibrationError, ValidationError
from .evaluation import (
    PoseError,
    StateErrors,
    align_frames,
    pose_error,
    pose_mapping_error,
    state_errors,
)
from ..radar.cluster import ClusterConfig
from ..data.recording import Detections, Recording, Tracks

__all__ = [
    "CONFIGURATION_NAMES",
    "TRAJECTORY_NAMES",
    "DemoConfig",
    "SingleTrack",
    "CalibrationOutcome",
    "FusionOutcome",
    "CubeStretch",
    "DemoResult",
    "single_target_track",
    "node_chain",
    "calibrate_run",
    "fuse_run",
    "simulate_run",
    "run_cube_stretch",
    "run_configuration",
    "run_demo",
    "other_trajectory",
]

CONFIGURATION_NAMES = ("A", "B", "C")
TRAJECTORY_NAMES = ("straight", "random")

#: The per-node EKF and the joint calibration graph of the demo use, as
#: measurement sigmas the simulator's torso-centroid errors (CentroidNoise:
#: 5 cm, 0.08 rad, 0.1 m/s), not the radar's resolutions: with the paper's pi/4 rad for the spatial frequency
#: the cross-range is hardly measured and, after each turn of the walker, a
#: track slides along its range circle (track RMSE 1.7 m on
#: data/config_C_straight.h5 against 0.04 m here). sigma_a = 1 m/s^2 instead
#: of the paper's 0.2: the simulated walker turns around at 1.5 m/s^2, which a
#: 0.2 m/s^2 model cannot follow (a new track after each turn).
#: The joint calibration with the paper's sigmas (0.035 m, pi/4, 0.18 m/s)
#: likewise nearly ignores the angles and lands farther from the true pose
#: than the closed form (configuration A: 0.11 m against 0.03 m).
#: The one-shot fusion keeps the paper's sigmas (the method under study).
DEMO_EKF_MEASUREMENT_STD = (0.05, 0.08, 0.10)
DEMO_EKF_SIGMA_A_MPS2 = 1.0


@dataclass(frozen=True, kw_only=True, slots=True)
class DemoConfig:
    """What the demo runs.

    configurations, trajectories : subsets of ``("A", "B", "C")`` and
        ``("straight", "random")``; the protocol needs both trajectories
        (calibrate on one, fuse the other); with one trajectory the run is
        calibrated and fused on the same data (flagged in the outputs).
    n_frames : frames per run (600 = the paper's 90 s at 150 ms).
    seed : every run's seed derives from it.
    cube_frames : frames of the raw-cube stretch (0: skip it).
    cube_configuration : configuration of the raw-cube stretch.
    max_lag_frames : frame-lag search of the track matching.
    """

    configurations: tuple[str, ...] = CONFIGURATION_NAMES
    trajectories: tuple[str, ...] = TRAJECTORY_NAMES
    n_frames: int = 600
    seed: int = 0
    cube_frames: int = 40
    cube_configuration: str = "C"
    max_lag_frames: int = 2

    def __post_init__(self) -> None:
        confs = tuple(str(c).upper() for c in self.configurations)
        trajs = tuple(str(t) for t in self.trajectories)
        if not confs or any(c not in CONFIGURATION_NAMES for c in confs):
            raise ValidationError(f"configurations={self.configurations!r} must be a non-empty "
                                  f"subset of {CONFIGURATION_NAMES}")
        if not trajs or any(t not in TRAJECTORY_NAMES for t in trajs):
            raise ValidationError(f"trajectories={self.trajectories!r} must be a non-empty "
                                  f"subset of {TRAJECTORY_NAMES}")
        if len(set(confs)) != len(confs) or len(set(trajs)) != len(trajs):
            raise ValidationError("configurations and trajectories must not repeat")
        object.__setattr__(self, "configurations", confs)
        object.__setattr__(self, "trajectories", trajs)
        if int(self.n_frames) != self.n_frames or self.n_frames < 20:
            raise ValidationError(f"n_frames={self.n_frames!r} must be an integer >= 20")
        if int(self.cube_frames) != self.cube_frames or self.cube_frames < 0:
            raise ValidationError(f"cube_frames={self.cube_frames!r} must be an integer >= 0")
        if str(self.cube_configuration).upper() not in CONFIGURATION_NAMES:
            raise ValidationError(f"cube_configuration={self.cube_configuration!r} must be one "
                                  f"of {CONFIGURATION_NAMES}")
        object.__setattr__(self, "cube_configuration", str(self.cube_configuration).upper())
        if int(self.max_lag_frames) != self.max_lag_frames or self.max_lag_frames < 0:
            raise ValidationError(f"max_lag_frames={self.max_lag_frames!r} must be an integer >= 0")

    @property
    def protocol(self) -> str:
        """``"cross"`` (calibrate on one trajectory, fuse the other) or
        ``"same"`` (one trajectory only: calibrate and fuse the same run)."""
        return "cross" if len(self.trajectories) >= 2 else "same"


def other_trajectory(trajectory: str, trajectories: Sequence[str]) -> str:
    """The trajectory whose calibration fuses ``trajectory``: the other one of
    the pair, or itself when only one was run."""
    others = [t for t in trajectories if t != trajectory]
    return others[0] if others else trajectory


def _run_seed(seed: int, configuration: str, trajectory: str) -> int:
    return int(seed) * 1000 + 10 * CONFIGURATION_NAMES.index(configuration) \
        + TRAJECTORY_NAMES.index(trajectory)


# ----------------------------------------------------------------------------
# Per-node chain from point clouds, single-target tracks
# ----------------------------------------------------------------------------


@dataclass(frozen=True, kw_only=True, slots=True)
class SingleTrack:
    """One target's local track of one node, one row per frame.

    frame : (K,) int; state : (K, 4) local ``(x_m, y_m, vx_mps, vy_mps)``;
    covariance : (K, 4, 4); track_id : (K,) which EKF track gave each row.
    """

    frame: NDArray
    state: NDArray
    covariance: NDArray
    track_id: NDArray

    def __len__(self) -> int:
        return int(self.frame.size)


def single_target_track(tracks: Tracks) -> SingleTrack:
    """Stitch a node's EKF tracks of one target into one row per frame.

    The EKF drops a track when the target turns faster than its
    white-acceleration model allows, and a new one starts (they overlap for a
    frame or two). Of the rows alive at a frame the one with the smallest
    position covariance trace is kept: the track being updated, not the one
    coasting before deletion.
    """
    if len(tracks) == 0:
        return SingleTrack(frame=np.zeros(0, np.int64), state=np.zeros((0, 4)),
                           covariance=np.zeros((0, 4, 4)), track_id=np.zeros(0, np.int64))
    tr = np.trace(tracks.covariance[:, :2, :2], axis1=1, axis2=2)
    order = np.lexsort((tr, tracks.frame))
    frames = tracks.frame[order]
    first = np.concatenate([[True], frames[1:] != frames[:-1]])
    rows = order[first]
    return SingleTrack(frame=tracks.frame[rows], state=tracks.state[rows],
                       covariance=tracks.covariance[rows], track_id=tracks.track_id[rows])


def node_chain(recording: Recording, *, cluster: ClusterConfig | None = None, ekf=None
               ) -> Recording:
    """Point cloud -> torso centroids (DBSCAN) -> local EKF tracks, per node
    (:func:`mmsnap_graph.app.pipeline.cluster_node`).

    ekf : default the demo's EKF (:data:`DEMO_EKF_MEASUREMENT_STD`,
    :data:`DEMO_EKF_SIGMA_A_MPS2`).

    Nodes without a point cloud keep their centroids (tracked if present).
    """
    from ..radar.chain import ChainConfig
    from .pipeline import cluster_node, track_node
    from ..tracking.ekf import EkfConfig

    chain = ChainConfig() if cluster is None else ChainConfig(cluster=cluster)
    if ekf is None:
        ekf = EkfConfig(measurement_std=DEMO_EKF_MEASUREMENT_STD,
                        sigma_a_mps2=DEMO_EKF_SIGMA_A_MPS2)
    rec = recording
    for name, node in recording.nodes.items():
        if node.point_cloud is not None:
            new, _ = cluster_node(node, recording.frame_period_s, chain=chain, ekf=ekf)
        elif node.centroids is not None:
            new, _ = track_node(node, recording.frame_period_s, ekf=ekf)
        else:
            raise ValidationError(f"node {name} has neither a point cloud nor centroids")
        rec = rec.with_node(new)
    return rec


def _centroids_near_track(centroids: Detections, track: SingleTrack) -> Detections:
    """One centroid per frame: the one nearest to the node's own track (a
    false-alarm cluster is never the target the node is tracking)."""
    if len(centroids) == 0 or len(track) == 0:
        return Detections.empty()
    from factors.models import detection_to_local

    pos = detection_to_local(centroids.range_m, centroids.omega_rad)
    idx = np.searchsorted(track.frame, centroids.frame)
    idx = np.clip(idx, 0, len(track) - 1)
    has = track.frame[idx] == centroids.frame
    dist = np.where(has, np.linalg.norm(pos - track.state[idx, :2], axis=1), np.inf)
    order = np.lexsort((dist, centroids.frame))
    f = centroids.frame[order]
    first = np.concatenate([[True], f[1:] != f[:-1]]) & np.isfinite(dist[order])
    return centroids.select(order[first])


# ----------------------------------------------------------------------------
# Calibration
# ----------------------------------------------------------------------------


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
    (:func:`mmsnap_graph.app.evaluation.pose_mapping_error`). n_frames : matched
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


def calibrate_run(recording: Recording, *, configuration: str = "?", trajectory: str = "?",
                  max_lag_frames: int = 2) -> CalibrationOutcome:
    """Calibrate S2 in S1's frame from a processed run (:func:`node_chain`).

    Closed form: :func:`mmsnap_graph.calibration.match_tracks` on each node's
    stitched single-target EKF track (frame-lag search). Refined:
    :func:`mmsnap_graph.calibration.joint_calibration` on the torso centroids
    (one per node and frame, the one on the node's track), started from the
    closed form, with the demo's centroid sigmas (:data:`DEMO_EKF_MEASUREMENT_STD`). Raises :class:`CalibrationError` when the closed form fails.
    """
    from ..calibration import LocalTracks, joint_calibration, match_tracks

    names = recording.node_names
    if len(names) != 2:
        raise ValidationError(f"the demo calibrates two-node networks, got nodes {names}")
    s1, s2 = (recording.nodes[n] for n in names)
    tracks = [single_target_track(n.tracks if n.tracks is not None else Tracks.empty())
              for n in (s1, s2)]
    lt = [LocalTracks(frame=t.frame, points_m=t.state[:, :2], track_id=np.zeros(len(t), np.int64))
          for t in tracks]
    m = match_tracks(lt[0], lt[1], max_lag_frames=max_lag_frames)
    if not m.success:
        raise CalibrationError(f"configuration {configuration}, {trajectory}: closed form "
                               f"failed: {m.message}")
    cf = m.calibration
    lag = int(m.lag_frames)
    dets = {}
    for name, node, tr in zip(names, (s1, s2), tracks):
        d = _centroids_near_track(node.centroids, tr)
        if name == names[1] and lag:
            d = dataclasses.replace(d, frame=d.frame - lag)
        dets[name] = d
    messages = [cf.message]
    try:
        joint = joint_calibration(dets, initial_poses={names[1]: cf.pose},
                                  sigmas=DEMO_EKF_MEASUREMENT_STD)
        refined_pose = np.asarray(joint.poses[names[1]], dtype=float)
        refined_cov = np.asarray(joint.covariances[names[1]], dtype=float)
        success = bool(joint.success)
        messages.append(joint.message)
    except CalibrationError as exc:
        refined_pose, refined_cov = cf.pose, cf.covariance
        success = False
        messages.append(f"refinement failed, closed form kept: {exc}")
    truth = recording.truth
    true_pose = (np.asarray(truth.node_poses[names[1]], dtype=float)
                 if truth is not None and names[1] in truth.node_poses else np.full(3, np.nan))
    nan_err = PoseError(position_error_m=float("nan"), heading_error_rad=float("nan"))
    has_truth = bool(np.all(np.isfinite(true_pose)))
    refined_rmse, _ = track_alignment_rmse(refined_pose, tracks[0], tracks[1], lag)
    t_frame = t_state = None
    map_cf = map_ref = float("nan")
    if truth is not None:
        t_frame, t_state = truth.target(int(truth.target_id.min()))
        if has_truth:
            map_cf = pose_mapping_error(cf.pose, true_pose, t_state[:, :2])
            map_ref = pose_mapping_error(refined_pose, true_pose, t_state[:, :2])
    return CalibrationOutcome(
        configuration=configuration, trajectory=trajectory,
        closed_form_pose=np.asarray(cf.pose, dtype=float),
        closed_form_covariance=np.asarray(cf.covariance, dtype=float),
        closed_form_rmse_m=float(cf.rmse_m), refined_pose=refined_pose,
        refined_covariance=refined_cov, refined_rmse_m=refined_rmse, true_pose=true_pose,
        closed_form_error=pose_error(cf.pose, true_pose) if has_truth else nan_err,
        refined_error=pose_error(refined_pose, true_pose) if has_truth else nan_err,
        n_frames=int(cf.n_frames), lag_frames=lag, success=success,
        message="; ".join(messages), closed_form_mapping_error_m=map_cf,
        refined_mapping_error_m=map_ref, track_s1=tracks[0], track_s2=tracks[1],
        truth_frame=t_frame, truth_state=t_state)


# ----------------------------------------------------------------------------
# Fusion
# ----------------------------------------------------------------------------


def _global_track(track: SingleTrack, pose: NDArray) -> tuple[NDArray, NDArray]:
    """A local single-target track in the global frame: states (K, 4) and
    covariances (K, 4, 4) (:func:`mmsnap_graph.tracking.track_fusion.transform_tracks`)."""
    from ..tracking.track_fusion import transform_tracks

    if len(track) == 0:
        return np.zeros((0, 4)), np.zeros((0, 4, 4))
    return transform_tracks(track.state, track.covariance, pose)


def track_level_fusion(frames: Sequence[NDArray], states: Sequence[NDArray],
                       covariances: Sequence[NDArray]) -> tuple[NDArray, NDArray]:
    """The paper's benchmark for two nodes: per frame, their single-target
    EKF tracks (already in the global frame) fused by covariance
    intersection with the trace-minimizing weight
    (:func:`mmsnap_graph.tracking.track_fusion.covariance_intersection`).

    frames : per node (K_i,) int, increasing; states : per node (K_i, 4);
    covariances : per node (K_i, 4, 4). Returns ``(frames (K,), states (K, 4))``
    on the frames both nodes have a track.
    """
    from ..tracking.track_fusion import covariance_intersection

    if len(frames) != 2:
        raise ValidationError(f"track-level fusion here takes two nodes, got {len(frames)}")
    common = np.intersect1d(frames[0], frames[1])
    if common.size == 0:
        return common, np.zeros((0, 4))
    i0 = np.searchsorted(frames[0], common)
    i1 = np.searchsorted(frames[1], common)
    x, _, _ = covariance_intersection(states[0][i0], covariances[0][i0],
                                      states[1][i1], covariances[1][i1])
    return common, x


def _one_row_per_frame(fused, n_nodes: int):
    """Rows of a FusedSequence with every node observing, one per frame (the
    lowest cost when association made several groups)."""
    ok = fused.observed.all(axis=1) if n_nodes > 1 else np.ones(len(fused), bool)
    rows = np.flatnonzero(ok)
    order = rows[np.lexsort((np.nan_to_num(fused.final_cost[rows], nan=np.inf), fused.frame[rows]))]
    f = fused.frame[order]
    first = np.concatenate([[True], f[1:] != f[:-1]]) if f.size else np.zeros(0, bool)
    return order[first]


@dataclass(frozen=True, kw_only=True, slots=True)
class FusionOutcome:
    """One-shot, track-level and central estimates of one run, per frame.

    frame : (K,) frames where both nodes detected the target and every
    estimate exists (the common frames of all metrics). truth, bayes, ml,
    track_fusion, central, ekf_s1, ekf_s2 : (K, 4) global states;
    bayes_covariance : (K, 4, 4) Laplace; degeneracy : (K,);
    measurements : (K, N, 3) the fused centroids.
    vs_track_fusion, vs_truth : name -> :class:`StateErrors`; vs_truth also
    has ``"bayes_closed_form"``: the Bayesian fusion with the closed-form
    instead of the refined pose.
    calibrated_on : the trajectory whose calibration was used.
    ml_flagged : frames (of the both-nodes frames) where ML failed.
    """

    configuration: str
    trajectory: str
    calibrated_on: str
    node_poses: NDArray
    frame: NDArray
    truth: NDArray
    bayes: NDArray
    bayes_covariance: NDArray
    ml: NDArray
    track_fusion: NDArray
    central: NDArray
    ekf_s1: NDArray
    ekf_s2: NDArray
    degeneracy: NDArray
    measurements: NDArray
    vs_track_fusion: Mapping[str, StateErrors]
    vs_truth: Mapping[str, StateErrors]
    ml_flagged: int
    n_both_frames: int
    message: str = ""

    def to_dict(self) -> dict:
        return {
            "configuration": self.configuration,
            "trajectory": self.trajectory,
            "calibrated_on": self.calibrated_on,
            "node_poses": self.node_poses.tolist(),
            "n_common_frames": int(self.frame.size),
            "n_both_frames": self.n_both_frames,
            "ml_flagged": self.ml_flagged,
            "degenerate_fraction": float(np.mean(self.degeneracy > _degeneracy_threshold()))
            if self.degeneracy.size else float("nan"),
            "vs_track_fusion": {k: v.to_dict() for k, v in self.vs_track_fusion.items()},
            "vs_truth": {k: v.to_dict() for k, v in self.vs_truth.items()},
            "message": self.message,
        }


def _fused_measurements(recording: Recording, fused, rows: NDArray) -> NDArray:
    """(K, N, 3) the centroids behind the fused rows (NaN where unobserved)."""
    names = recording.node_names
    out = np.full((rows.size, len(names), 3), np.nan)
    for j, n in enumerate(names):
        idx = fused.detection_index[rows, j]
        has = idx >= 0
        out[has, j] = recording.nodes[n].centroids.measurements[idx[has]]
    return out


def _degeneracy_threshold() -> float:
    from ..fusion.oneshot import DEGENERACY_THRESHOLD

    return float(DEGENERACY_THRESHOLD)


def fuse_run(recording: Recording, calibration: CalibrationOutcome, *, configuration: str = "?",
             trajectory: str = "?") -> FusionOutcome:
    """One-shot (Bayesian and ML), track-level and central estimates of a
    processed run (:func:`node_chain`) with ``calibration``'s refined pose.

    One-shot: :func:`mmsnap_graph.fusion.sequence.fuse_recording` of the torso
    centroids (MAP with the paper's prior; ML). Track-level fusion: the two
    nodes' stitched EKF tracks in S1's frame, fused by covariance intersection
    (:func:`track_level_fusion`). Central tracker:
    :func:`mmsnap_graph.tracking.central.track_fused` fed by the MAP
    estimates. All are compared on the frames where both nodes detected the
    target and every estimate exists.
    """
    from ..fusion.sequence import fuse_recording
    from ..tracking.central import CentralConfig, track_fused

    names = recording.node_names
    poses = {names[0]: np.zeros(3), names[1]: np.asarray(calibration.refined_pose, dtype=float)}
    pose_arr = np.stack([poses[n] for n in names])
    fused = {mode: fuse_recording(recording, node_poses=poses, mode=mode, progress=False)
             for mode in ("map", "ml")}
    # The same Bayesian fusion with the closed-form poses: what the refinement buys downstream.
    cf_poses = {names[0]: np.zeros(3),
                names[1]: np.asarray(calibration.closed_form_pose, dtype=float)}
    fused["map_cf"] = fuse_recording(recording, node_poses=cf_poses, mode="map", progress=False)
    rows = {mode: _one_row_per_frame(f, len(names)) for mode, f in fused.items()}
    frames_both = fused["map"].frame[rows["map"]]
    central = single_target_track(track_fused(
        fused["map"], CentralConfig(frame_period_s=recording.frame_period_s,
                                    sigma_a_mps2=DEMO_EKF_SIGMA_A_MPS2)))
    tracks = [single_target_track(recording.nodes[n].tracks) for n in names]
    ekf_global = [_global_track(t, poses[n]) for t, n in zip(tracks, names)]
    tlf_frames, tlf_state = track_level_fusion(
        [t.frame for t in tracks], [g[0] for g in ekf_global], [g[1] for g in ekf_global])
    truth = recording.truth
    if truth is None:
        raise ValidationError("the demo's runs need a recording with truth")
    t_frames, t_states = truth.target(int(truth.target_id.min()))

    # Common frames of everything.
    common = frames_both
    for fr in (fused["ml"].frame[rows["ml"]], tlf_frames, central.frame, tracks[0].frame,
               tracks[1].frame, t_frames):
        common = np.intersect1d(common, fr)

    def at(frames_src, values):
        idx = np.searchsorted(frames_src, common)
        return values[idx]

    def at_or_nan(frames_src, values):
        idx = np.clip(np.searchsorted(frames_src, common), 0, max(frames_src.size - 1, 0))
        ok = frames_src[idx] == common if frames_src.size else np.zeros(common.size, bool)
        out = np.full((common.size,) + values.shape[1:], np.nan)
        out[ok] = values[idx[ok]]
        return out

    fm, fl = fused["map"], fused["ml"]
    map_rows = at(fm.frame[rows["map"]], rows["map"])
    ml_rows = at(fl.frame[rows["ml"]], rows["ml"])
    bayes = fm.state[map_rows]
    ml = fl.state[ml_rows]
    ok_ml = fl.success[ml_rows]
    ml = np.where(ok_ml[:, None], ml, np.nan)
    est = {
        "bayes": bayes,
        "ml": ml,
        "track_fusion": at(tlf_frames, tlf_state),
        "central": at(central.frame, central.state),
        "ekf_s1": at(tracks[0].frame, ekf_global[0][0]),
        "ekf_s2": at(tracks[1].frame, ekf_global[1][0]),
        "bayes_closed_form": at_or_nan(fused["map_cf"].frame[rows["map_cf"]],
                                       fused["map_cf"].state[rows["map_cf"]]),
    }
    ref_truth = at(t_frames, t_states)
    vs_tlf = {k: state_errors(est[k], est["track_fusion"]) for k in ("bayes", "ml")}
    vs_truth = {k: state_errors(v, ref_truth) for k, v in est.items()}
    ml_rows_both = rows["ml"]
    ml_flagged = int(np.count_nonzero(~fl.success[ml_rows_both]))
    return FusionOutcome(
        configuration=configuration, trajectory=trajectory,
        calibrated_on=calibration.trajectory, node_poses=pose_arr, frame=common,
        truth=ref_truth, bayes=bayes, bayes_covariance=fm.covariance[map_rows], ml=ml,
        track_fusion=est["track_fusion"], central=est["central"], ekf_s1=est["ekf_s1"],
        ekf_s2=est["ekf_s2"], degeneracy=fm.degeneracy[map_rows],
        measurements=_fused_measurements(recording, fm, map_rows), vs_track_fusion=vs_tlf,
        vs_truth=vs_truth, ml_flagged=ml_flagged, n_both_frames=int(frames_both.size),
        message=f"{common.size} common frames of {frames_both.size} with both nodes")


# ----------------------------------------------------------------------------
# Runs: data, the raw-cube stretch, configurations, the whole demo
# ----------------------------------------------------------------------------


def truncate_recording(recording: Recording, n_frames: int) -> Recording:
    """The first ``n_frames`` frames of a recording (detections, tracks and
    truth; cubes are dropped)."""
    n = int(n_frames)
    rec = recording
    for name, node in recording.nodes.items():
        kw = {}
        for level in ("point_cloud", "centroids"):
            d = getattr(node, level)
            if d is not None:
                kw[level] = d.select(d.frame < n)
        if node.tracks is not None:
            kw["tracks"] = node.tracks.select(node.tracks.frame < n)
        rec = rec.with_node(dataclasses.replace(node, cube=None, cube_frame=None, **kw))
    if recording.truth is not None:
        t = recording.truth
        keep = t.frame < n
        rec = dataclasses.replace(rec, truth=dataclasses.replace(
            t, frame=t.frame[keep], target_id=t.target_id[keep], state=t.state[keep]))
    return rec


def sample_path(data_dir, configuration: str, trajectory: str):
    """``<data_dir>/config_<C>_<trajectory>.h5`` (the sample recordings'
    naming, data/README.md)."""
    from pathlib import Path

    return Path(data_dir) / f"config_{configuration}_{trajectory}.h5"


def simulate_run(configuration: str, trajectory: str, *, n_frames: int, seed: int) -> Recording:
    """A simulated run at the point-cloud level (one walking person)."""
    from ..sim import simulate_recording

    return simulate_recording(configuration, trajectory, levels=("point_cloud",),
                              n_frames=n_frames, seed=_run_seed(seed, configuration, trajectory))


def load_run(configuration: str, trajectory: str, *, n_frames: int, seed: int, data_dir=None
             ) -> tuple[Recording, str]:
    """The run's recording and where it came from: the sample file in
    ``data_dir`` when it exists (first ``n_frames`` frames), else simulated."""
    if data_dir is not None:
        path = sample_path(data_dir, configuration, trajectory)
        if path.is_file():
            from ..io import read_recording

            rec = read_recording(path, load_cubes=False)
            if rec.truth is None:
                raise ValidationError(f"{path} has no truth; the demo needs simulated data")
            return truncate_recording(rec, n_frames), str(path)
    return (simulate_run(configuration, trajectory, n_frames=n_frames, seed=seed),
            f"simulated (seed {_run_seed(seed, configuration, trajectory)})")


@dataclass(frozen=True, kw_only=True, slots=True)
class CubeStretch:
    """The full chain from raw ADC cubes on a short recording.

    source : where the cubes came from. n_frames : frames with cubes.
    n_points, n_centroids, n_track_rows : per node. centroid_rms : node ->
    RMS error of the torso centroid ``(range_m, omega_rad, doppler_mps)``
    against the true torso's measurement (frames with a centroid).
    detection_rate : node -> fraction of frames with a centroid.
    fused_vs_truth : MAP one-shot with the true poses against the truth
    (None when no frame has both nodes). seconds : wall time.
    """

    source: str
    configuration: str
    n_frames: int
    n_points: Mapping[str, int]
    n_centroids: Mapping[str, int]
    n_track_rows: Mapping[str, int]
    centroid_rms: Mapping[str, list]
    detection_rate: Mapping[str, float]
    fused_vs_truth: StateErrors | None
    seconds: float
    message: str = ""

    def to_dict(self) -> dict:
        return {
            "source": self.source, "configuration": self.configuration,
            "n_frames": self.n_frames, "n_points": dict(self.n_points),
            "n_centroids": dict(self.n_centroids), "n_track_rows": dict(self.n_track_rows),
            "centroid_rms": {k: list(v) for k, v in self.centroid_rms.items()},
            "detection_rate": dict(self.detection_rate),
            "fused_vs_truth": None if self.fused_vs_truth is None else self.fused_vs_truth.to_dict(),
            "seconds": self.seconds, "message": self.message,
        }


def run_cube_stretch(recording: Recording, *, source: str, configuration: str = "?",
                     progress: bool = False) -> CubeStretch:
    """Raw cubes -> FFTs, OS-CFAR -> torso DBSCAN -> EKF on every node
    (:func:`mmsnap_graph.app.pipeline.process_recording`), then one-shot
    fusion with the true poses; errors against the truth."""
    from factors.models import wrap_angle

    from .pipeline import process_recording
    from ..fusion.sequence import fuse_recording

    t0 = time.perf_counter()
    if any(n.cube is None for n in recording.nodes.values()):
        raise ValidationError(f"{source}: every node needs raw cubes for the cube stretch")
    rec, reports = process_recording(recording, progress=progress)
    truth = recording.truth
    if truth is None:
        raise ValidationError(f"{source}: the cube stretch needs truth")
    tid = int(truth.target_id.min())
    t_frames, t_states = truth.target(tid)
    n_frames = int(next(iter(recording.nodes.values())).cube.shape[0])
    rms, rate = {}, {}
    for name, node in rec.nodes.items():
        c = node.centroids
        pose = truth.node_poses[name]
        idx = np.searchsorted(t_frames, c.frame)
        idx = np.clip(idx, 0, t_frames.size - 1)
        ok = t_frames[idx] == c.frame
        h, _ = measurement_model(t_states[idx[ok]], pose)
        err = c.measurements[ok] - h
        err[:, 1] = wrap_angle(err[:, 1])
        # Nearest centroid to the truth per frame (false-alarm clusters aside).
        f = c.frame[ok]
        d = np.abs(err[:, 0])
        order = np.lexsort((d, f))
        first = np.concatenate([[True], f[order][1:] != f[order][:-1]]) if f.size else \
            np.zeros(0, bool)
        e = err[order[first]]
        rms[name] = [float(np.sqrt(np.mean(e[:, i] ** 2))) if e.size else float("nan")
                     for i in range(3)]
        rate[name] = float(e.shape[0] / max(n_frames, 1))
    fused_err = None
    msg = "; ".join(f"{k}: {r.message}" for k, r in reports.items())
    try:
        fused = fuse_recording(rec, node_poses=dict(truth.node_poses), mode="map", progress=False)
        rows = _one_row_per_frame(fused, len(rec.node_names))
        fr = fused.frame[rows]
        _, ia, ib = align_frames(fr, t_frames)
        if ia.size:
            fused_err = state_errors(fused.state[rows][ia], t_states[ib])
    except ValidationError as exc:
        msg += f"; fusion skipped: {exc}"
    return CubeStretch(
        source=source, configuration=configuration, n_frames=n_frames,
        n_points={k: len(n.point_cloud) for k, n in rec.nodes.items()},
        n_centroids={k: len(n.centroids) for k, n in rec.nodes.items()},
        n_track_rows={k: len(n.tracks) for k, n in rec.nodes.items()},
        centroid_rms=rms, detection_rate=rate, fused_vs_truth=fused_err,
        seconds=time.perf_counter() - t0, message=msg)


@dataclass(frozen=True, kw_only=True, slots=True)
class DemoResult:
    """Everything the demo computed.

    calibrations : (configuration, trajectory) -> :class:`CalibrationOutcome`
        (calibrated on that trajectory). fusions : (configuration, trajectory)
        -> :class:`FusionOutcome` (that trajectory fused with the other's
        calibration). sources : (configuration, trajectory) -> where the run's
        data came from. cube_stretches : the raw-cube runs. seconds : stage ->
        wall time.
    """

    config: DemoConfig
    calibrations: Mapping[tuple[str, str], CalibrationOutcome]
    fusions: Mapping[tuple[str, str], FusionOutcome]
    sources: Mapping[tuple[str, str], str]
    cube_stretches: tuple[CubeStretch, ...]
    seconds: Mapping[str, float]
    failures: tuple[str, ...] = ()

    def to_dict(self) -> dict:
        return {
            "config": {k: (list(v) if isinstance(v, tuple) else v)
                       for k, v in dataclasses.asdict(self.config).items()},
            "protocol": self.config.protocol,
            "sources": {f"{c}/{t}": s for (c, t), s in self.sources.items()},
            "calibration": {f"{c}/{t}": v.to_dict() for (c, t), v in self.calibrations.items()},
            "fusion": {f"{c}/{t}": v.to_dict() for (c, t), v in self.fusions.items()},
            "cube_stretches": [c.to_dict() for c in self.cube_stretches],
            "seconds": dict(self.seconds),
            "failures": list(self.failures),
        }


def run_configuration(configuration: str, config: DemoConfig, *, data_dir=None,
                      on_stage: Callable[[str], None] | None = None):
    """Calibrate and fuse both trajectories of one configuration.

    Returns ``(calibrations, fusions, sources, failures)`` keyed by trajectory.
    """
    step = on_stage or (lambda _msg: None)
    recs, sources = {}, {}
    for traj in config.trajectories:
        step(f"{configuration}/{traj}: DBSCAN torso + EKF")
        rec, src = load_run(configuration, traj, n_frames=config.n_frames, seed=config.seed,
                            data_dir=data_dir)
        recs[traj] = node_chain(rec)
        sources[traj] = src
    cals, fusions, failures = {}, {}, []
    for traj in config.trajectories:
        step(f"{configuration}/{traj}: calibration")
        try:
            cals[traj] = calibrate_run(recs[traj], configuration=configuration, trajectory=traj,
                                       max_lag_frames=config.max_lag_frames)
        except CalibrationError as exc:
            failures.append(f"{configuration}/{traj}: calibration failed: {exc}")
    for traj in config.trajectories:
        cal_traj = other_trajectory(traj, config.trajectories)
        if cal_traj not in cals:
            failures.append(f"{configuration}/{traj}: not fused (no calibration from {cal_traj})")
            continue
        step(f"{configuration}/{traj}: fusion")
        fusions[traj] = fuse_run(recs[traj], cals[cal_traj], configuration=configuration,
                                 trajectory=traj)
    return cals, fusions, sources, failures


def find_sample_data(path=None):
    """The sample-data folder: ``path`` when given (must exist), else
    ``./data`` or the repository's ``data/`` when they hold the samples, else
    None (the demo simulates)."""
    from pathlib import Path

    if path is not None:
        p = Path(path)
        if not p.is_dir():
            raise ValidationError(f"data folder {str(p)!r} does not exist")
        return p
    for cand in (Path.cwd() / "data", Path(__file__).resolve().parents[1] / "data"):
        if sample_path(cand, "C", "straight").is_file():
            return cand
    return None


def run_demo(config: DemoConfig | None = None, *, data_dir=None, progress: bool = False,
             cube_recording_paths: Sequence = ()) -> DemoResult:
    """The whole demo (module docstring). ``data_dir``: sample recordings
    (``config_<C>_<trajectory>.h5``) used instead of simulating when present;
    ``cube_recording_paths``: HDF5 recordings with raw cubes to run the full
    chain on, in addition to the simulated cube stretch."""
    from pathlib import Path

    from tqdm.auto import tqdm

    config = DemoConfig() if config is None else config
    seconds: dict[str, float] = {}
    cubes = []
    n_steps = len(config.configurations) * len(config.trajectories) * 3 + \
        len(cube_recording_paths) + (1 if config.cube_frames else 0)
    bar = tqdm(total=n_steps, desc="mmsnap demo", unit="step", disable=not progress)
    try:
        t0 = time.perf_counter()
        for path in cube_recording_paths:
            from ..io import read_recording

            bar.set_postfix_str(f"raw-cube chain: {path}")
            rec = read_recording(path)
            conf = str(rec.metadata.get("network", "?"))
            cubes.append(run_cube_stretch(rec, source=f"sample {Path(path).name}",
                                          configuration=conf))
            bar.update(1)
        if config.cube_frames:
            from ..sim import simulate_recording

            bar.set_postfix_str(f"raw cubes: {config.cube_configuration}, {config.cube_frames} frames")
            seed = _run_seed(config.seed, config.cube_configuration, "straight") + 500
            rec = simulate_recording(config.cube_configuration, "straight", levels=("cube",),
                                     n_frames=config.cube_frames, seed=seed)
            cubes.append(run_cube_stretch(
                rec, source=f"simulated raw ADC cubes (seed {seed})",
                configuration=config.cube_configuration))
            bar.update(1)
        seconds["raw_cube_chain"] = time.perf_counter() - t0
        cals, fus, srcs, fails = {}, {}, {}, []
        t0 = time.perf_counter()

        started = [False]

        def stage(msg):
            # Called when a stage starts: the previous one is done.
            if started[0]:
                bar.update(1)
            started[0] = True
            bar.set_postfix_str(msg)

        for conf in config.configurations:
            c, f, s, fl = run_configuration(conf, config, data_dir=data_dir, on_stage=stage)
            cals.update({(conf, t): v for t, v in c.items()})
            fus.update({(conf, t): v for t, v in f.items()})
            srcs.update({(conf, t): v for t, v in s.items()})
            fails.extend(fl)
        if started[0]:
            bar.update(1)
        seconds["configurations"] = time.perf_counter() - t0
    finally:
        bar.close()
    return DemoResult(config=config, calibrations=cals, fusions=fus, sources=srcs,
                      cube_stretches=tuple(cubes), seconds=seconds, failures=tuple(fails))
