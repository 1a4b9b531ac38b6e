"""A whole recording scored against its truth (``mmsnap evaluate``).

The metrics themselves live in :mod:`mmsnap_graph.evaluation`; this module
picks what a recording holds (fused rows, each node's tracks, calibrated
poses), places the tracks with the poses and gathers the numbers into one
JSON-ready dict.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from ..data.results import DEGENERACY_THRESHOLD
from ..errors import ValidationError
from ..evaluation.metrics import nees_check, pose_error, pose_mapping_error, state_errors, truth_reference
from ..tracking.track_fusion import transform_tracks

__all__ = ["evaluate_recording", "failed_checks"]


def _nees_summary(err: NDArray, cov: NDArray) -> dict:
    check = nees_check(err, cov, confidence=0.95)
    return {"mean": check.mean, "n": check.n, "interval_95": list(check.interval),
            "passed": check.passed}


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
            "degenerate_fraction": float(np.mean(deg > DEGENERACY_THRESHOLD))
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
