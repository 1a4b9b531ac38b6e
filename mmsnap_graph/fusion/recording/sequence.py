"""One-shot fusion of a whole recording (paper Sec. III-B, frame after frame).

:func:`fuse_recording` takes every frame of a recording, groups the nodes'
centroids into targets (:mod:`mmsnap_graph.fusion.association`), and fuses each group
with the calibrated node poses: MAP (the paper's Bayesian estimate) or ML,
with the Laplace covariance or the paper's grid covariance. A frame where only
some nodes see a target is fused with the nodes that do; a frame that cannot
be fused is flagged (``success`` False, a :class:`~mmsnap_graph.data.results.Status`
and a message), never raised.

Each group is solved through the one contract,
:func:`mmsnap_graph.fusion.solve.robust_solve`, with any of its solvers
(``"vectorized"``, the default, over many frames; ``"gtsam"``, one factor
graph per frame; ``"scalar"``), which give the same answers; with pose covariances (:class:`~mmsnap_graph.fusion.options.NetworkCalibration`)
their covariances differ by a few percent
(docs/CONVENTIONS.md, "Calibration-aware fusion").

The result can be stored in the recording's HDF5 file as a ``/fused`` group
(:func:`mmsnap_graph.io.fused.write_fused`, :func:`mmsnap_graph.io.fused.read_fused`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, Mapping, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from factors.models import detection_to_global

from ..association import (
    associate_frame,
    detection_information,
    detection_position_covariance,
    gate_threshold,
)
from ..config import DEFAULT_CONFIG, FusionConfig
from ..problem import check_node_noise, check_pose_covariances
from ..options import NetworkCalibration
from ..solve import check_grid_model
from .pipeline import FusionNetwork, fuse_rows, screen_rows
from .coverage import coverage_reach_m
from .regroup import merge_body_detections
from .room import RoomReport
from .timing import align_recording, offset_ranges
from ...data.noise import MeasurementNoise
from ...data.recording import Recording
from ...data.results import FusedSequence
from ...errors import CalibrationError, MissingStepError, ValidationError
from ..._validation import check_pose
from ...tracking.person_ids import assign_person_ids

__all__ = [
    "FusedSequence",
    "fuse_recording",
    "fuse_recording_report",
    "fuse_recording_rows",
    "recording_network",
    "calibrated_recording",
    "recording_poses",
    "group_detections",
]

# ----------------------------------------------------------------------------
# Poses
# ----------------------------------------------------------------------------


def recording_poses(
    recording: Recording, node_poses: Mapping[str, ArrayLike] | None = None
) -> NDArray:
    """(N, 3) poses of the recording's nodes, in its order: from ``node_poses``
    (e.g. :func:`~mmsnap_graph.io.calibration.load_calibration_poses`) when
    given, else the poses stored in the recording. A node without a pose
    raises :class:`CalibrationError`."""
    out = []
    for name in recording.node_names:
        if node_poses is not None:
            if name not in node_poses:
                raise CalibrationError(
                    f"the calibration has no pose for node {name!r} "
                    f"(it has {sorted(node_poses)})"
                )
            pose = node_poses[name]
        else:
            pose = recording.nodes[name].pose
            if pose is None:
                raise MissingStepError(
                    f"node {name!r} has no pose in the recording; calibrate it or pass "
                    "calibration poses", step="calibrate",
                    what=f"node {name!r} has no pose in the recording")
        out.append(check_pose(pose, f"pose of {name}"))
    return np.stack(out)


# ----------------------------------------------------------------------------
# Grouping the centroids into targets
# ----------------------------------------------------------------------------


@dataclass(frozen=True, kw_only=True, slots=True)
class DetectionGroups:
    """K groups of detections (one target in one frame), sorted by frame then target.

    frame, target, label : (K,) int; detection_index : (K, N) int, -1 where a
    node has no member; measurements : (K, N, 3), zeros where unobserved.
    """

    frame: NDArray
    target: NDArray
    label: NDArray
    detection_index: NDArray
    measurements: NDArray


@dataclass(frozen=True, kw_only=True, slots=True)
class _FrameIndex:
    """Per node, the detection rows of each frame as ``(start, count)`` in frame order."""

    frames: NDArray  # (F,) every frame with a detection
    order: list  # per node: detection rows sorted by frame
    starts: NDArray  # (F, N)
    counts: NDArray  # (F, N)

    def rows(self, fi: int, n: int) -> NDArray:
        return self.order[n][self.starts[fi, n]:self.starts[fi, n] + self.counts[fi, n]]


def _frame_index(frames_of: list) -> _FrameIndex:
    all_frames = np.unique(np.concatenate(frames_of))
    n_f, n_nodes = all_frames.size, len(frames_of)
    order = [np.argsort(f, kind="stable") for f in frames_of]
    counts = np.zeros((n_f, n_nodes), dtype=np.int64)
    starts = np.zeros((n_f, n_nodes), dtype=np.int64)
    for n in range(n_nodes):
        pos = np.searchsorted(all_frames, frames_of[n][order[n]])
        c = np.bincount(pos, minlength=n_f)
        counts[:, n] = c
        starts[:, n] = np.concatenate([[0], np.cumsum(c)[:-1]])
    return _FrameIndex(frames=all_frames, order=order, starts=starts, counts=counts)


def _single_gate(index: _FrameIndex, meas, poses, noise, gate):
    """The vectorized pass: ``(first_row (F, N), ok (F,))``, ``ok`` for frames
    where every node has at most one detection and all fall in one gate."""
    n_f, n_nodes = index.counts.shape
    single = np.all(index.counts <= 1, axis=1)
    first_row = np.full((n_f, n_nodes), -1, dtype=np.int64)
    for n in range(n_nodes):
        has = index.counts[:, n] == 1
        first_row[has, n] = index.order[n][index.starts[has, n]]
    info = np.zeros((n_f, 2, 2))
    eta = np.zeros((n_f, 2))
    joint_ok = single.copy()
    for n in range(n_nodes):
        rows = first_row[:, n]
        has = single & (rows >= 0)
        if not np.any(has):
            continue
        z = meas[n][rows[has]]
        with np.errstate(all="ignore"):
            p = detection_to_global(z[:, 0], z[:, 1], poses[n])
            c = detection_position_covariance(z[:, 0], z[:, 1], poses[n], noise[n])
        ic, regular = detection_information(c)
        # A degenerate detection (range 0, tiny sigmas): its frame goes
        # through associate_frame, which gives it a group of its own.
        joint_ok[np.flatnonzero(has)[~regular]] = False
        p = np.where(regular[:, None], p, 0.0)
        c = np.where(regular[:, None, None], c, np.eye(2))
        started = np.abs(info[has]).sum(axis=(1, 2)) > 0
        if np.any(started):
            hs = np.flatnonzero(has)[started]
            cov_g = np.linalg.inv(info[hs])
            mean_g = np.einsum("fij,fj->fi", cov_g, eta[hs])
            d = mean_g - p[started]
            s = cov_g + c[started]
            m2 = np.einsum("fi,fi->f", d, np.linalg.solve(s, d[..., None])[..., 0])
            joint_ok[hs[m2 > gate]] = False
        info[has] += ic
        eta[has] += np.einsum("fij,fj->fi", ic, p)
    return first_row, joint_ok


def _group_rows(index: _FrameIndex, meas, poses, noise, gate_probability):
    """``(frame, target, detection_index)`` of every group, sorted."""
    n_nodes = len(meas)
    gate = gate_threshold(gate_probability)
    first_row, joint_ok = _single_gate(index, meas, poses, noise, gate)
    fast = np.flatnonzero(joint_ok & np.any(first_row >= 0, axis=1))
    frame_l = [index.frames[fast]]
    target_l = [np.zeros(fast.size, dtype=np.int64)]
    index_l = [first_row[fast]]
    # The other frames one by one (identical results where both apply).
    for fi in np.flatnonzero(~joint_ok):
        rows_n = [index.rows(fi, n) for n in range(n_nodes)]
        per_node = [meas[n][r] if r.size else np.zeros((0, 3)) for n, r in enumerate(rows_n)]
        assoc = associate_frame(per_node, poses, noise, gate_probability=gate_probability)
        g = len(assoc)
        idx = np.full((g, n_nodes), -1, dtype=np.int64)
        for n in range(n_nodes):
            m = assoc.members[:, n] >= 0
            idx[m, n] = rows_n[n][assoc.members[m, n]]
        frame_l.append(np.full(g, index.frames[fi]))
        target_l.append(np.arange(g, dtype=np.int64))
        index_l.append(idx)
    frame = np.concatenate(frame_l)
    target = np.concatenate(target_l)
    rows = np.concatenate(index_l)
    srt = np.lexsort((target, frame))
    return frame[srt], target[srt], rows[srt]


def _measurements_and_labels(dets, meas, rows):
    """``(measurements (K, N, 3), label (K,))`` of the groups ``rows (K, N)``."""
    k, n_nodes = rows.shape
    z = np.zeros((k, n_nodes, 3))
    labels = np.full((k, n_nodes), -1, dtype=np.int64)
    for n in range(n_nodes):
        has = rows[:, n] >= 0
        if np.any(has):
            z[has, n] = meas[n][rows[has, n]]
            if dets[n].target_id is not None:
                labels[has, n] = dets[n].target_id[rows[has, n]]
    obs = rows >= 0
    lab = np.where(obs, labels, np.iinfo(np.int64).max).min(axis=1)
    agree = np.all(~obs | (labels == lab[:, None]), axis=1) & (lab >= 0) & obs.any(axis=1)
    return z, np.where(agree, lab, -1)


def group_detections(
    recording: Recording,
    node_poses: ArrayLike,
    noise: MeasurementNoise | Sequence[MeasurementNoise] | Mapping[str, MeasurementNoise] = (
        MeasurementNoise()),
    *,
    gate_probability: float = 0.999,
    source: Literal["centroids", "point_cloud"] = "centroids",
    merge_body_m: float | None = None,
) -> DetectionGroups:
    """Group every frame's detections into targets (see
    :mod:`mmsnap_graph.fusion.association`; ``noise`` sets the gates: one
    :class:`MeasurementNoise`, one per node in the recording's node order, or a
    mapping by node name holding every node).
    Returns K groups sorted by frame then target.

    ``merge_body_m`` (metres; None: off): a node's centroids of one frame
    closer than this are one body split into clusters, merged first
    (:func:`~.regroup.merge_body_detections`; a merged group's
    ``detection_index`` is its first centroid's row).

    Frames where every node has at most one detection and all of them fall in
    one gate are grouped in a vectorized pass; the others go through
    :func:`~mmsnap_graph.fusion.association.associate_frame` one by one (identical
    results).
    """
    poses = np.asarray(node_poses, dtype=float)
    noise = check_node_noise(noise, len(recording.node_names), recording.node_names)
    dets = [getattr(recording.nodes[name], source) for name in recording.node_names]
    if all(d is None or len(d) == 0 for d in dets):
        raise ValidationError(f"no node of the recording has {source}; nothing to fuse")
    meas = [None if d is None else d.measurements for d in dets]
    kept = [None if d is None else np.arange(len(d)) for d in dets]
    if merge_body_m is not None and source == "centroids":
        for n, d in enumerate(dets):
            if d is not None and len(d):
                keep, merged = merge_body_detections(d.frame, meas[n], merge_body_m)
                kept[n] = np.flatnonzero(keep)
                dets[n], meas[n] = d.select(kept[n]), merged[kept[n]]
    index = _frame_index([np.zeros(0, np.int64) if d is None else d.frame for d in dets])
    frame, target, rows = _group_rows(index, meas, poses, noise, gate_probability)
    z, label = _measurements_and_labels(dets, meas, rows)
    for n, k in enumerate(kept):  # back to the recording's detection rows
        if k is not None:
            has = rows[:, n] >= 0
            rows[has, n] = k[rows[has, n]]
    return DetectionGroups(frame=frame, target=target, label=label, detection_index=rows,
                           measurements=z)


# ----------------------------------------------------------------------------
# Fusion
# ----------------------------------------------------------------------------


def recording_network(recording: Recording, calibration: NetworkCalibration, noise,
                      config: FusionConfig) -> FusionNetwork:
    """The :class:`~.pipeline.FusionNetwork` of ``recording`` (in its node
    order) with ``calibration``'s poses and pose covariances, ``noise`` (one
    :class:`MeasurementNoise`, or a mapping holding every node) and the
    configuration's prior, validated once; a node missing from the pose
    covariances has an exact pose."""
    names = tuple(recording.node_names)
    noise = check_node_noise(noise, len(names), names)
    covs = calibration.pose_covariances
    pose_cov = check_pose_covariances(None if covs is None else dict(covs), len(names), names)
    net = FusionNetwork.make(names, recording_poses(recording, calibration.node_poses), noise,
                             pose_cov, config.prior, recording.frame_period_s)
    check_grid_model(net.problem, config.solve)
    return net


def calibrated_recording(recording: Recording, calibration: NetworkCalibration,
                         source: str = "centroids") -> Recording:
    """The recording as fusion sees it: the centroids on the reference clock
    (``calibration.time_offset_s``) and with the calibration's range offset
    added (``calibration.range_offset_m``)."""
    if calibration.time_offset_s:
        if source != "centroids":
            raise ValidationError("calibration.time_offset_s aligns the centroids: use "
                                  "source='centroids'")
        recording = align_recording(recording, calibration.time_offset_s)
    if calibration.range_offset_m is not None:
        if source != "centroids":
            raise ValidationError("calibration.range_offset_m moves the centroids' ranges: use "
                                  "source='centroids'")
        recording = offset_ranges(recording, calibration.range_offset_m)
    return recording


def check_calibration(calibration: object) -> NetworkCalibration:
    """``calibration`` (None: an empty one) as a :class:`NetworkCalibration`."""
    cal = NetworkCalibration() if calibration is None else calibration
    if not isinstance(cal, NetworkCalibration):
        raise ValidationError(f"calibration must be a NetworkCalibration, got "
                              f"{type(cal).__name__}")
    return cal


def fuse_recording_rows(
    recording: Recording,
    config: FusionConfig = DEFAULT_CONFIG,
    *,
    calibration: NetworkCalibration | None = None,
    noise: MeasurementNoise | Mapping[str, MeasurementNoise] = MeasurementNoise(),
    progress: bool | None = None,
) -> FusedSequence:
    """:func:`fuse_recording` before the checks in the reference frame (room,
    learned walls, duplicates: :func:`~.pipeline.screen_rows`)."""
    if not isinstance(config, FusionConfig):
        raise ValidationError(f"config must be a FusionConfig, got {type(config).__name__}")
    if not isinstance(recording, Recording):
        raise ValidationError(f"recording must be a Recording, got {type(recording).__name__}")
    if progress is not None and not isinstance(progress, (bool, np.bool_)):
        raise ValidationError(f"progress must be True, False or None, got {progress!r}")
    cal = check_calibration(calibration)
    assoc = config.association
    # How far each node looks: declared by the file (mmsnap live's), else from
    # its detections before the offsets move them (as a file's reader takes them).
    config = config.with_coverage_reach(coverage_reach_m(recording))
    recording = calibrated_recording(recording, cal, assoc.source)
    net = recording_network(recording, cal, noise, config)
    groups = group_detections(recording, net.poses, net.noise,
                              gate_probability=assoc.gate_probability, source=assoc.source,
                              merge_body_m=assoc.merge_body_m)
    return fuse_rows(groups.frame, groups.target, groups.label, groups.detection_index,
                     groups.measurements, net, config, progress=progress,
                     time_origin_s=_time_origin(recording.metadata))


def fuse_recording_report(
    recording: Recording,
    config: FusionConfig = DEFAULT_CONFIG,
    *,
    calibration: NetworkCalibration | None = None,
    noise: MeasurementNoise | Mapping[str, MeasurementNoise] = MeasurementNoise(),
    progress: bool | None = None,
) -> tuple[FusedSequence, RoomReport]:
    """:func:`fuse_recording`, and what its room checks flagged (a
    :class:`~.room.RoomReport`: counts and the learned walls)."""
    fused, report = screen_rows(fuse_recording_rows(recording, config, calibration=calibration,
                                                    noise=noise, progress=progress), config)
    return assign_person_ids(fused), report


def fuse_recording(
    recording: Recording,
    config: FusionConfig = DEFAULT_CONFIG,
    *,
    calibration: NetworkCalibration | None = None,
    noise: MeasurementNoise | Mapping[str, MeasurementNoise] = MeasurementNoise(),
    progress: bool | None = None,
) -> FusedSequence:
    """Fuse every target in every frame of ``recording`` (the in-memory
    driver of the one pipeline, :mod:`~.pipeline`).

    Parameters
    ----------
    recording : Recording
        Its nodes' ``centroids`` (or ``point_cloud``) are fused.
    config : FusionConfig
        How (:class:`~mmsnap_graph.fusion.config.FusionConfig`, default
        :data:`~mmsnap_graph.fusion.config.DEFAULT_CONFIG`, what ``mmsnap
        fuse`` does): the association, the solve (``config.solve.solver``
        ``"vectorized"`` or ``"gtsam"``; ``config.solve.covariance``
        ``"laplace"`` or ``"grid"``, the paper's numerical posterior
        covariance, :func:`mmsnap_graph.fusion.grid.grid_posterior`; slow),
        the prior (None: ML), the robust fit and the checks.
        :data:`~mmsnap_graph.fusion.config.PLAIN_CONFIG`: plain one-shot
        fusion of each frame.
    calibration : NetworkCalibration, optional
        The network's calibration (:class:`~mmsnap_graph.fusion.options.NetworkCalibration`;
        None: the poses stored in the recording, nothing else), its parts:
        ``node_poses`` (e.g.
        :func:`~mmsnap_graph.io.calibration.load_calibration_poses`) replace
        the recording's poses. ``pose_covariances``: calibration-aware fusion
        (docs/CONVENTIONS.md, "Calibration-aware fusion"): each node pose's
        covariance in the Pose2 body tangent (the calibration's marginals);
        a node left out (or all NaN / all zero) has an exact pose. The
        estimates do not change; ``covariance`` and ``laplace_covariance``
        include the poses'. Needs ``covariance="laplace"``.
        ``time_offset_s``: each node's clock offset (node time + offset =
        reference time): the centroids are brought to the reference clock
        first (:func:`mmsnap_graph.fusion.recording.timing.align_recording`:
        whole frames, then the range by Doppler times the rest); a node left
        out keeps its clock. ``range_offset_m``: the calibration's range
        offset (an extended target's reflection depth), added to every
        centroid's range first
        (:func:`~mmsnap_graph.fusion.recording.timing.offset_ranges`), so
        that the fused state is the body's centre; its uncertainty is not in
        the fused covariances.
    noise : MeasurementNoise (every node; default the paper's) or a mapping
        ``{node name: MeasurementNoise}`` holding every fused node (per-node
        noise, docs/CONVENTIONS.md); used by the association and the fusion.
    progress : show a tqdm bar (default: when stderr is a terminal).
    The rows' ``track_id``: :func:`~mmsnap_graph.tracking.person_ids.assign_person_ids`
    (the tracker, the pipeline's last stage, after every check).
    """
    return fuse_recording_report(recording, config, calibration=calibration, noise=noise,
                                 progress=progress)[0]


def _time_origin(metadata) -> float | None:
    """The recording's wall-clock origin (Unix seconds of time 0), if valid."""
    try:
        value = float(metadata.get("time_origin_s"))
    except (AttributeError, TypeError, ValueError):
        return None
    return value if np.isfinite(value) else None
