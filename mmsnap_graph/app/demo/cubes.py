"""The demo's raw-cube stretch: a short recording with raw ADC cubes through
the whole per-node chain (:func:`mmsnap_graph.app.pipeline.process_recording`)
and one-shot fusion with the true poses (:mod:`mmsnap_graph.app.demo`)."""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Mapping

import numpy as np
from numpy.typing import NDArray

from factors.models import measurement_model, wrap_angle

from ...data.recording import Detections, Recording
from ...errors import ValidationError
from ...fusion.config import PLAIN_CONFIG
from ...fusion.options import NetworkCalibration
from ...fusion.recording.sequence import fuse_recording
from .fusion import one_row_per_frame
from ...evaluation.metrics import StateErrors, align_frames, state_errors
from ..pipeline import process_recording

__all__ = ["CubeStretch", "run_cube_stretch"]


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


def _centroid_errors(centroids: Detections, pose: NDArray, t_frames: NDArray,
                     t_states: NDArray) -> NDArray:
    """(K, 3) errors of the centroid nearest in range to the true torso's
    measurement, one per frame with a centroid (false-alarm clusters aside)."""
    idx = np.searchsorted(t_frames, centroids.frame)
    idx = np.clip(idx, 0, t_frames.size - 1)
    ok = t_frames[idx] == centroids.frame
    h, _ = measurement_model(t_states[idx[ok]], pose)
    err = centroids.measurements[ok] - h
    err[:, 1] = wrap_angle(err[:, 1])
    f = centroids.frame[ok]
    order = np.lexsort((np.abs(err[:, 0]), f))
    first = np.concatenate([[True], f[order][1:] != f[order][:-1]]) if f.size else \
        np.zeros(0, bool)
    return err[order[first]]


def _fused_errors(rec: Recording, node_poses, t_frames: NDArray, t_states: NDArray
                  ) -> StateErrors | None:
    """MAP one-shot fusion with the true poses against the truth (None when
    no frame has every node)."""
    fused = fuse_recording(rec, PLAIN_CONFIG,
                           calibration=NetworkCalibration(node_poses=dict(node_poses)),
                           progress=False)
    rows = one_row_per_frame(fused, len(rec.node_names))
    _, ia, ib = align_frames(fused.frame[rows], t_frames)
    return state_errors(fused.state[rows][ia], t_states[ib]) if ia.size else None


def run_cube_stretch(recording: Recording, *, source: str, configuration: str = "?",
                     progress: bool = False) -> CubeStretch:
    """Raw cubes -> FFTs, OS-CFAR -> torso DBSCAN -> EKF on every node
    (:func:`mmsnap_graph.app.pipeline.process_recording`), then one-shot
    fusion with the true poses; errors against the truth."""
    t0 = time.perf_counter()
    if any(n.cube is None for n in recording.nodes.values()):
        raise ValidationError(f"{source}: every node needs raw cubes for the cube stretch")
    rec, reports = process_recording(recording, progress=progress)
    truth = recording.truth
    if truth is None:
        raise ValidationError(f"{source}: the cube stretch needs truth")
    t_frames, t_states = truth.target(int(truth.target_id.min()))
    n_frames = int(next(iter(recording.nodes.values())).cube.shape[0])
    rms, rate = {}, {}
    for name, node in rec.nodes.items():
        e = _centroid_errors(node.centroids, truth.node_poses[name], t_frames, t_states)
        rms[name] = [float(np.sqrt(np.mean(e[:, i] ** 2))) if e.size else float("nan")
                     for i in range(3)]
        rate[name] = float(e.shape[0] / max(n_frames, 1))
    fused_err = None
    msg = "; ".join(f"{k}: {r.message}" for k, r in reports.items())
    try:
        fused_err = _fused_errors(rec, truth.node_poses, t_frames, t_states)
    except ValidationError as exc:
        msg += f"; fusion skipped: {exc}"
    return CubeStretch(
        source=source, configuration=configuration, n_frames=n_frames,
        n_points={k: len(n.point_cloud) for k, n in rec.nodes.items()},
        n_centroids={k: len(n.centroids) for k, n in rec.nodes.items()},
        n_track_rows={k: len(n.tracks) for k, n in rec.nodes.items()},
        centroid_rms=rms, detection_rate=rate, fused_vs_truth=fused_err,
        seconds=time.perf_counter() - t0, message=msg)
