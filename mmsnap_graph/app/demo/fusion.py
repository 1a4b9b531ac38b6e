"""The demo's fusion of one run with a calibration: one-shot (Bayesian and
ML), track-level fusion (the paper's benchmark,
:func:`mmsnap_graph.tracking.track_fusion.fuse_tracks`) and the central
tracker, all on the frames they have in common (:mod:`mmsnap_graph.app.demo`)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Mapping

import numpy as np
from numpy.typing import NDArray

from ...data.recording import Recording
from ...errors import ValidationError
from ...data.results import DEGENERACY_THRESHOLD
from ...data.results import FusedSequence
from ...fusion.config import PLAIN_CONFIG
from ...fusion.options import NetworkCalibration
from ...fusion.recording.sequence import fuse_recording
from ...tracking.central import CentralConfig, track_fused
from ...tracking.track_fusion import fuse_tracks, transform_tracks
from .calibration import CalibrationOutcome
from .chain import DEMO_EKF_SIGMA_A_MPS2, SingleTrack, single_target_track
from ...evaluation.metrics import StateErrors, state_errors

__all__ = [
    "FusionOutcome",
    "one_row_per_frame",
    "fused_measurements",
    "global_track",
    "track_level_fusion",
    "fuse_run",
]


def _fuse(recording: Recording, node_poses: Mapping[str, NDArray], mode: str) -> FusedSequence:
    """One-shot fusion of every frame of a run: ``mode`` "map" (the paper's
    prior) or "ml"."""
    config = PLAIN_CONFIG if mode == "map" else dataclasses.replace(PLAIN_CONFIG, prior=None)
    return fuse_recording(recording, config,
                          calibration=NetworkCalibration(node_poses=dict(node_poses)),
                          progress=False)


def one_row_per_frame(fused: FusedSequence, n_nodes: int) -> NDArray:
    """Rows of a fused sequence with every node observing, one per frame (the
    lowest cost when association made several groups)."""
    ok = fused.observed.all(axis=1) if n_nodes > 1 else np.ones(len(fused), bool)
    rows = np.flatnonzero(ok)
    order = rows[np.lexsort((np.nan_to_num(fused.final_cost[rows], nan=np.inf), fused.frame[rows]))]
    f = fused.frame[order]
    first = np.concatenate([[True], f[1:] != f[:-1]]) if f.size else np.zeros(0, bool)
    return order[first]


def global_track(track: SingleTrack, pose: NDArray) -> tuple[NDArray, NDArray]:
    """A local single-target track in the global frame: states (K, 4) and
    covariances (K, 4, 4) (:func:`mmsnap_graph.tracking.track_fusion.transform_tracks`)."""
    if len(track) == 0:
        return np.zeros((0, 4)), np.zeros((0, 4, 4))
    return transform_tracks(track.state, track.covariance, pose)


def track_level_fusion(tracks: tuple[SingleTrack, SingleTrack], poses: tuple[NDArray, NDArray]
                       ) -> tuple[NDArray, NDArray]:
    """The paper's benchmark for two nodes: per frame, their single-target
    EKF tracks moved into the global frame with ``poses`` and fused by
    covariance intersection with the trace-minimizing weight
    (:func:`mmsnap_graph.tracking.track_fusion.fuse_tracks`, ungated: each
    node has one track per frame, on the same target).

    Returns ``(frames (K,), states (K, 4))`` on the frames both nodes have a
    track, in increasing order.
    """
    if len(tracks) != 2 or len(poses) != 2:
        raise ValidationError(f"track-level fusion here takes two nodes, got {len(tracks)}")
    fused = fuse_tracks(tracks[0].as_tracks(), poses[0], tracks[1].as_tracks(), poses[1],
                        gate_probability=None)
    return fused.frame, fused.state


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
            "degenerate_fraction": float(np.mean(self.degeneracy > DEGENERACY_THRESHOLD))
            if self.degeneracy.size else float("nan"),
            "vs_track_fusion": {k: v.to_dict() for k, v in self.vs_track_fusion.items()},
            "vs_truth": {k: v.to_dict() for k, v in self.vs_truth.items()},
            "message": self.message,
        }


def fused_measurements(recording: Recording, fused: FusedSequence, rows: NDArray) -> NDArray:
    """(K, N, 3) the centroids behind the fused rows (NaN where unobserved)."""
    names = recording.node_names
    out = np.full((rows.size, len(names), 3), np.nan)
    for j, n in enumerate(names):
        idx = fused.detection_index[rows, j]
        has = idx >= 0
        out[has, j] = recording.nodes[n].centroids.measurements[idx[has]]
    return out


def _at(frames_src: NDArray, values: NDArray, common: NDArray) -> NDArray:
    """``values`` at the ``common`` frames (all present in ``frames_src``)."""
    return values[np.searchsorted(frames_src, common)]


def _at_or_nan(frames_src: NDArray, values: NDArray, common: NDArray) -> NDArray:
    """``values`` at the ``common`` frames, NaN where ``frames_src`` lacks one."""
    idx = np.clip(np.searchsorted(frames_src, common), 0, max(frames_src.size - 1, 0))
    ok = frames_src[idx] == common if frames_src.size else np.zeros(common.size, bool)
    out = np.full((common.size,) + values.shape[1:], np.nan)
    out[ok] = values[idx[ok]]
    return out


def _estimate_run(recording: Recording, calibration: CalibrationOutcome) -> dict:
    """Every estimator of the run, each as per-frame ``(frames, states)``
    (frames increasing), plus what the outcome needs of the one-shot fusion."""
    names = recording.node_names
    poses = {names[0]: np.zeros(3), names[1]: np.asarray(calibration.refined_pose, dtype=float)}
    fused = {mode: _fuse(recording, poses, mode) for mode in ("map", "ml")}
    # The same Bayesian fusion with the closed-form poses: what the refinement buys downstream.
    cf_poses = {names[0]: np.zeros(3),
                names[1]: np.asarray(calibration.closed_form_pose, dtype=float)}
    fused["map_cf"] = _fuse(recording, cf_poses, "map")
    rows = {mode: one_row_per_frame(f, len(names)) for mode, f in fused.items()}
    central = single_target_track(track_fused(
        fused["map"], CentralConfig(frame_period_s=recording.frame_period_s,
                                    sigma_a_mps2=DEMO_EKF_SIGMA_A_MPS2)))
    tracks = tuple(single_target_track(recording.nodes[n].tracks) for n in names)
    pose_pair = tuple(poses[n] for n in names)
    series = {mode: (fused[mode].frame[rows[mode]], fused[mode].state[rows[mode]])
              for mode in ("map", "ml", "map_cf")}
    series["track_fusion"] = track_level_fusion(tracks, pose_pair)
    series["central"] = (central.frame, central.state)
    for key, t, pose in zip(("ekf_s1", "ekf_s2"), tracks, pose_pair):
        series[key] = (t.frame, global_track(t, pose)[0])
    return dict(names=names, poses=poses, fused=fused, rows=rows, series=series)


def fuse_run(recording: Recording, calibration: CalibrationOutcome, *, configuration: str = "?",
             trajectory: str = "?") -> FusionOutcome:
    """One-shot (Bayesian and ML), track-level and central estimates of a
    processed run (:func:`mmsnap_graph.app.demo.chain.node_chain`) with
    ``calibration``'s refined pose.

    One-shot: :func:`mmsnap_graph.fusion.recording.sequence.fuse_recording` of the torso
    centroids (MAP with the paper's prior; ML). Track-level fusion: the two
    nodes' stitched EKF tracks in S1's frame, fused by covariance intersection
    (:func:`track_level_fusion`). Central tracker:
    :func:`mmsnap_graph.tracking.central.track_fused` fed by the MAP
    estimates. All are compared on the frames where both nodes detected the
    target and every estimate exists.
    """
    truth = recording.truth
    if truth is None:
        raise ValidationError("the demo's runs need a recording with truth")
    run = _estimate_run(recording, calibration)
    series, fused, rows = run["series"], run["fused"], run["rows"]
    t_frames, t_states = truth.target(int(truth.target_id.min()))
    frames_both = series["map"][0]
    common = frames_both
    for key in ("ml", "track_fusion", "central", "ekf_s1", "ekf_s2"):
        common = np.intersect1d(common, series[key][0])
    common = np.intersect1d(common, t_frames)

    fm, fl = fused["map"], fused["ml"]
    map_rows = _at(frames_both, rows["map"], common)
    ml_rows = _at(series["ml"][0], rows["ml"], common)
    est = {k: _at(*series[k], common) for k in ("track_fusion", "central", "ekf_s1", "ekf_s2")}
    est = {"bayes": fm.state[map_rows],
           "ml": np.where(fl.success[ml_rows][:, None], fl.state[ml_rows], np.nan),
           **est, "bayes_closed_form": _at_or_nan(*series["map_cf"], common)}
    ref_truth = _at(t_frames, t_states, common)
    return FusionOutcome(
        configuration=configuration, trajectory=trajectory,
        calibrated_on=calibration.trajectory,
        node_poses=np.stack([run["poses"][n] for n in run["names"]]), frame=common,
        truth=ref_truth, bayes=est["bayes"], bayes_covariance=fm.covariance[map_rows],
        ml=est["ml"], track_fusion=est["track_fusion"], central=est["central"],
        ekf_s1=est["ekf_s1"], ekf_s2=est["ekf_s2"], degeneracy=fm.degeneracy[map_rows],
        measurements=fused_measurements(recording, fm, map_rows),
        vs_track_fusion={k: state_errors(est[k], est["track_fusion"]) for k in ("bayes", "ml")},
        vs_truth={k: state_errors(v, ref_truth) for k, v in est.items()},
        ml_flagged=int(np.count_nonzero(~fl.success[rows["ml"]])),
        n_both_frames=int(frames_both.size),
        message=f"{common.size} common frames of {frames_both.size} with both nodes")
