"""Calibrate every node of a recording, and store the result.

:func:`calibrate_recording` chains the steps: each node's local tracks (EKF
tracks when the recording has them, else centroids mapped to local xy),
track matching and lag search for every node pair, the pose graph anchored
at the reference (first) node, and -- when every calibrated node has one
centroid per frame -- the joint calibration graph on the raw centroid
measurements, started from the pose graph.

:func:`write_calibration` stores the result in the recording, atomically:
each calibrated node's ``pose`` attribute (through
:func:`mmsnap_graph.io.update_recording`) and a ``/calibration`` group
(layout in :data:`CALIBRATION_LAYOUT`), in one temporary copy moved over the
file. :meth:`RecordingCalibration.to_json` gives the project's calibration
JSON (``{"reference": "S1", "nodes": {"S1": {"pose": [x_m, y_m, phi_rad],
"covariance": [[3x3]]}, ...}, ...}``, covariance in the Pose2 body tangent).
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, Mapping

import numpy as np
from numpy.typing import NDArray

from .._atomic import atomic_path
from ..errors import CalibrationError, FileFormatError, ValidationError
from ..data.recording import Detections, Recording
from .joint import PAPER_SIGMAS, JointCalibration, joint_calibration
from .matching import LocalTracks, local_tracks
from .pose_graph import PoseEdge, PoseGraphCalibration, pairwise_edges, pose_graph_calibration

__all__ = ["RecordingCalibration", "calibrate_recording", "residual_sigmas", "write_calibration",
           "write_calibration_json", "CALIBRATION_GROUP", "CALIBRATION_LAYOUT"]

CALIBRATION_GROUP = "calibration"
#: Layout of the ``/calibration`` group written by :func:`write_calibration`.
CALIBRATION_LAYOUT = """\
/calibration           attrs: reference (str), method (str), source (str),
                              success (bool), message (str), json (str: to_json())
    node_name          (N,) str, every node of the recording in order
    calibrated         (N,) bool, False for nodes with no path to the reference
    pose               (N, 3) float (x_m, y_m, phi_rad), NaN where not calibrated
    covariance         (N, 3, 3) float, Pose2 body tangent, NaN where not calibrated
    lag_frames         (N,) int, node frame k + lag = reference frame k (0 if unknown)
    edges/             one row per pairwise estimate:
        node_a, node_b (E,) str; pose (E, 3); covariance (E, 3, 3);
        rmse_m (E,) float (paper eq. 14); n_frames (E,) int; lag_frames (E,) int
"""


@dataclass(frozen=True, kw_only=True, slots=True)
class RecordingCalibration:
    """Every node's calibrated pose in the reference frame.

    poses, covariances, lag_frames : per calibrated node.
    unreachable : nodes with no path of matched tracks to the reference.
    edges : the pairwise closed-form estimates (with track RMSE and lag).
    method : ``"joint"`` when the joint graph refined the poses, else
    ``"pose_graph"``. source : ``"tracks"`` or ``"centroids"``.
    pose_graph, joint : the step results.
    """

    reference: str
    node_names: tuple[str, ...]
    poses: Mapping[str, NDArray]
    covariances: Mapping[str, NDArray]
    lag_frames: Mapping[str, int]
    unreachable: tuple[str, ...]
    edges: tuple[PoseEdge, ...]
    method: str
    source: str
    success: bool
    message: str
    failures: Mapping[str, str] = field(default_factory=dict)
    pose_graph: PoseGraphCalibration | None = None
    joint: JointCalibration | None = None

    def to_json(self) -> dict[str, Any]:
        """The project's calibration JSON as a dict (``json.dumps``-able;
        non-finite numbers become None)."""

        num = _jsonable
        nodes = {}
        for n in self.node_names:
            if n in self.poses:
                nodes[n] = {"pose": num(self.poses[n]), "covariance": num(self.covariances[n]),
                            "lag_frames": int(self.lag_frames.get(n, 0))}
        return {
            "reference": self.reference,
            "nodes": nodes,
            "unreachable": list(self.unreachable),
            "method": self.method,
            "source": self.source,
            "success": bool(self.success),
            "message": self.message,
            "edges": [{"node_a": e.node_a, "node_b": e.node_b, "pose": num(e.pose),
                       "covariance": num(e.covariance), "rmse_m": num(e.rmse_m),
                       "n_frames": int(e.n_frames), "lag_frames": int(e.lag_frames)}
                      for e in self.edges],
            "failures": dict(self.failures),
        }


def _jsonable(x):
    """Floats and nested lists for JSON; NaN and infinity become None."""
    a = np.asarray(x, dtype=float)
    if a.ndim == 0:
        return float(a) if np.isfinite(a) else None
    return [_jsonable(v) for v in a]


def _metadata_sigmas(metadata) -> tuple[float, float, float] | None:
    keys = ("centroid_range_std_m", "centroid_omega_std_rad", "centroid_doppler_std_mps")
    try:
        vals = tuple(float(metadata[k]) for k in keys)
    except (KeyError, TypeError, ValueError):
        return None
    return vals if all(np.isfinite(v) and v > 0 for v in vals) else None


def residual_sigmas(result: JointCalibration, detections: Mapping[str, Detections], *,
                    sigmas, prior_sigmas=(1e3, 1e3, 3.5, 3.5), n_rounds: int = 3,
                    min_redundancy: float = 0.1) -> NDArray:
    """Noise of each measurement component (range_m, omega_rad, doppler_mps)
    from the inlier residuals of a joint solution *without motion factors*
    (the leverages treat frames apart), corrected for what each
    frame's state absorbs (leverage):

    .. math:: \\hat\\sigma_c^2 = \\sum e_c^2 / \\sum (1 - h_c),

    ``h`` the diagonal of the per-frame hat matrix ``J (J^T W J + P)^{-1}
    J^T W`` (the states at fixed poses), iterated ``n_rounds`` times since
    ``W`` depends on the sigmas. A component whose residuals carry less than
    ``min_redundancy`` of a degree of freedom per measurement is not
    identifiable (e.g. the Doppler of two nodes without motion factors fits
    each frame's velocity exactly) and keeps its value in ``sigmas``. (3,).
    """
    from factors.models import measurement_model, residual

    sig = np.asarray(sigmas, dtype=float).copy()
    prior_w = 1.0 / np.asarray(prior_sigmas, dtype=float) ** 2
    rows = []  # (frame index, residual (3,), Jacobian (3, 4)) per inlier detection
    for n, det in detections.items():
        if n not in result.poses:
            continue
        idx = np.clip(np.searchsorted(result.frames, det.frame), 0, result.frames.size - 1)
        hit = result.frames[idx] == det.frame
        keep = hit.copy()
        keep[hit] = ~result.outliers[n][idx[hit]]
        h, jac = measurement_model(result.states[idx[keep]], result.poses[n])
        rows.append((idx[keep], residual(h, det.measurements[keep]), jac))
    if not rows or sum(r[0].size for r in rows) == 0:
        raise CalibrationError("no inlier detection to estimate the noise from")
    f = result.frames.size
    for _ in range(n_rounds):
        info = np.tile(np.diag(prior_w), (f, 1, 1))
        for k, _, jac in rows:
            np.add.at(info, k, np.einsum("kri,r,krj->kij", jac, 1.0 / sig**2, jac))
        cov = np.linalg.inv(info)
        num, den = np.zeros(3), np.zeros(3)
        for k, e, jac in rows:
            lev = np.einsum("kri,kij,krj->kr", jac, cov[k], jac) / sig**2
            num += np.sum(e**2, axis=0)
            den += np.sum(1.0 - lev, axis=0)
        count = sum(r[0].size for r in rows)
        ok = den > min_redundancy * count
        sig = np.where(ok, np.sqrt(num / np.maximum(den, 1e-300)), sig)
    return sig


def _joint_detections(rec: Recording, names, lags) -> dict[str, Detections] | None:
    """Each node's centroids on the reference's frame clock, or None when a
    node has no centroids or several per frame (the joint graph needs one
    detection of the common target per node per frame)."""
    out = {}
    for n in names:
        det = rec.nodes[n].centroids
        if det is None or len(det) == 0 or np.unique(det.frame).size != det.frame.size:
            return None
        out[n] = dataclasses.replace(det, frame=det.frame - int(lags.get(n, 0)))
    return out


def calibrate_recording(
    recording: Recording,
    *,
    source: Literal["auto", "tracks", "centroids"] = "auto",
    method: Literal["auto", "joint", "pose_graph"] = "auto",
    max_lag_frames: int = 2,
    max_rmse_m: float = 1.0,
    sigmas=None,
    robust: str | None = "cauchy",
    motion: bool = True,
    sigma_a_mps2: float = 3.0,
) -> RecordingCalibration:
    """Calibrate every node of ``recording`` (module doc).

    method : ``"pose_graph"`` stops after the pose graph of pairwise closed
        forms; ``"joint"`` requires the joint refinement (CalibrationError if
        the centroids cannot feed it); ``"auto"`` refines when it can.
    max_lag_frames, max_rmse_m : track matching (:func:`match_tracks`).
    sigmas : (3,) measurement noise of the centroids for the joint graph;
        None: the recording's ``centroid_range_std_m``,
        ``centroid_omega_std_rad``, ``centroid_doppler_std_mps`` metadata
        (the simulator writes them), else estimated from the residuals of a
        first joint solve (:func:`residual_sigmas`) whose spatial-frequency
        sigma comes from the closed form's track RMSE.
        Wrong sigmas cost accuracy: the joint graph weighs range against
        spatial frequency by them.
    robust, motion, sigma_a_mps2 : joint graph (:func:`joint_calibration`).
        The constant-velocity factors let a ghost stand out from the smooth
        track (without them a free per-frame state absorbs part of it); their
        white-acceleration sigma must cover a walking person's accelerations:
        on the simulator's walks 0.5 m/s^2 biased the poses by up to 9 cm,
        2-5 m/s^2 did not (default 3).
    Raises :class:`CalibrationError` when no node pair can be matched.
    """
    if method not in ("auto", "joint", "pose_graph"):
        raise ValidationError(f"method={method!r} must be 'auto', 'joint' or 'pose_graph'")
    names = list(recording.node_names)
    if len(names) < 2:
        raise CalibrationError(f"a calibration needs at least two nodes, got {names!r}")
    ref = names[0]
    tracks: dict[str, LocalTracks] = {}
    failures: dict[str, str] = {}
    for n in names:
        try:
            tracks[n] = local_tracks(recording.nodes[n], source)
        except CalibrationError as exc:
            failures[n] = str(exc)
    if ref not in tracks:
        raise CalibrationError(f"reference node {ref}: {failures[ref]}")
    used_source = tracks[ref].source
    edges, pair_fail = pairwise_edges(tracks, max_lag_frames=max_lag_frames, max_rmse_m=max_rmse_m)
    failures.update(pair_fail)
    if not edges:
        raise CalibrationError("no pair of nodes shares a matched track: "
                               + "; ".join(f"{k}: {v}" for k, v in failures.items()))
    pg = pose_graph_calibration(names, edges, failures=failures)
    poses, covs, lags = dict(pg.poses), dict(pg.covariances), dict(pg.lag_frames)
    result_method, joint, notes = "pose_graph", None, [pg.message]
    reachable = [n for n in names if n in poses]
    if method in ("auto", "joint") and len(reachable) >= 2:
        dets = _joint_detections(recording, reachable, lags)
        if dets is None:
            if method == "joint":
                raise CalibrationError("the joint calibration needs one centroid per node per "
                                       "frame; some node has none or several")
            notes.append("joint refinement skipped: needs one centroid per node per frame")
        else:
            kw = dict(initial_poses=poses, robust=robust, motion=motion,
                      frame_period_s=recording.frame_period_s, sigma_a_mps2=sigma_a_mps2)
            if sigmas is None:
                sigmas = _metadata_sigmas(recording.metadata)
                if sigmas is None:
                    # First guess: the cross-range noise the closed form's
                    # track RMSE implies (RMSE^2 ~ two nodes' cross-range
                    # variances) as omega = pi x / r; the paper's range and
                    # Doppler sigmas. Then the residuals of that solve.
                    rmse = float(np.median([e.rmse_m for e in pg.edges]))
                    mean_range = float(np.mean(np.concatenate(
                        [d.range_m for d in dets.values()])))
                    omega0 = float(np.clip(np.pi * rmse / (np.sqrt(2.0) * mean_range), 0.01,
                                           PAPER_SIGMAS[1]))
                    # Two rounds (the weights move the solution, the
                    # solution the residuals); no motion factors in these
                    # solves: the leverage correction treats frames apart.
                    sigmas = (PAPER_SIGMAS[0], omega0, PAPER_SIGMAS[2])
                    for _ in range(2):
                        first = joint_calibration(dets, sigmas=sigmas, **{**kw, "motion": False})
                        sigmas = residual_sigmas(first, dets, sigmas=sigmas)
                    notes.append("sigmas estimated from residuals: "
                                 + ", ".join(f"{v:.3g}" for v in sigmas))
            joint = joint_calibration(dets, sigmas=sigmas, **kw)
            notes.append(joint.message)
            if joint.success or method == "joint":
                poses = {n: joint.poses[n] for n in reachable}
                covs = {n: joint.covariances[n] for n in reachable}
                result_method = "joint"
            else:
                notes.append("kept the pose-graph poses")
    success = pg.success and (joint is None or joint.success or result_method == "pose_graph")
    return RecordingCalibration(
        reference=ref, node_names=tuple(names), poses=poses, covariances=covs, lag_frames=lags,
        unreachable=pg.unreachable, edges=pg.edges, method=result_method, source=used_source,
        success=bool(success), message="; ".join(notes), failures=failures, pose_graph=pg,
        joint=joint)


def _atomic_copy_edit(src: Path, dst: Path, edit) -> Path:
    """Copy ``src`` beside ``dst``, let ``edit`` change the copy, move it over ``dst``."""
    with atomic_path(dst) as tmp:
        shutil.copyfile(src, tmp)
        edit(tmp)
    return dst


def write_calibration(path: str | os.PathLike, recording: Recording, cal: RecordingCalibration,
                      *, output: str | os.PathLike | None = None) -> Path:
    """Store ``cal`` in the recording file at ``path`` (or a copy at
    ``output``): calibrated nodes' ``pose`` attributes and the
    ``/calibration`` group (:data:`CALIBRATION_LAYOUT`), atomically.

    ``recording`` is the file's content (e.g. ``read_recording(path,
    load_cubes=False)``); cubes not loaded are kept.
    """
    import h5py

    from ..io import update_recording

    src = Path(path)
    if not src.exists():
        raise FileFormatError(f"{src} does not exist")
    dst = src if output is None else Path(output)
    rec = recording
    for n, pose in cal.poses.items():
        rec = rec.with_node(dataclasses.replace(rec.nodes[n], pose=np.asarray(pose, dtype=float)))

    def edit(tmp: Path) -> None:
        update_recording(tmp, rec, keep_cubes=True)
        with h5py.File(tmp, "r+") as f:
            if CALIBRATION_GROUP in f:
                del f[CALIBRATION_GROUP]
            g = f.create_group(CALIBRATION_GROUP)
            names = list(cal.node_names)
            n = len(names)
            pose = np.full((n, 3), np.nan)
            cov = np.full((n, 3, 3), np.nan)
            lag = np.zeros(n, np.int64)
            ok = np.zeros(n, bool)
            for i, name in enumerate(names):
                if name in cal.poses:
                    pose[i], cov[i], ok[i] = cal.poses[name], cal.covariances[name], True
                    lag[i] = cal.lag_frames.get(name, 0)
            str_t = h5py.string_dtype()
            g.attrs["reference"] = cal.reference
            g.attrs["method"] = cal.method
            g.attrs["source"] = cal.source
            g.attrs["success"] = bool(cal.success)
            g.attrs["message"] = cal.message
            g.attrs["json"] = json.dumps(cal.to_json())
            g.create_dataset("node_name", data=np.array(names, dtype=object), dtype=str_t)
            g.create_dataset("calibrated", data=ok)
            g.create_dataset("pose", data=pose)
            g.create_dataset("covariance", data=cov)
            g.create_dataset("lag_frames", data=lag)
            e = g.create_group("edges")
            edges = cal.edges
            e.create_dataset("node_a", data=np.array([x.node_a for x in edges], dtype=object),
                             dtype=str_t)
            e.create_dataset("node_b", data=np.array([x.node_b for x in edges], dtype=object),
                             dtype=str_t)
            e.create_dataset("pose", data=np.array([x.pose for x in edges]).reshape(-1, 3))
            e.create_dataset("covariance",
                             data=np.array([x.covariance for x in edges]).reshape(-1, 3, 3))
            e.create_dataset("rmse_m", data=np.array([x.rmse_m for x in edges], dtype=float))
            e.create_dataset("n_frames", data=np.array([x.n_frames for x in edges], np.int64))
            e.create_dataset("lag_frames", data=np.array([x.lag_frames for x in edges], np.int64))

    return _atomic_copy_edit(src, dst, edit)


def write_calibration_json(path: str | os.PathLike, cal: RecordingCalibration) -> Path:
    """Write :meth:`RecordingCalibration.to_json` to ``path``, atomically."""
    dst = Path(path)
    with atomic_path(dst) as tmp:
        tmp.write_text(json.dumps(cal.to_json(), indent=2) + "\n")
    return dst
