"""One-shot fusion of a whole recording (paper Sec. III-B, frame after frame).

:func:`fuse_recording` takes every frame of a recording, groups the nodes'
centroids into targets (:mod:`mmsnap_graph.fusion.association`), and fuses each group
with the calibrated node poses: MAP (the paper's Bayesian estimate) or ML,
with the Laplace covariance or the paper's grid covariance. A frame where only
some nodes see a target is fused with the nodes that do; a frame that cannot
be fused is flagged (``success`` False, a :class:`~mmsnap_graph.data.results.Status`
and a message), never raised.

Two solvers give the same answers (the tests compare them):
``"vectorized"`` (:func:`mmsnap_graph.fusion.solvers.vectorized.fuse_batch`, vectorized over frames)
and ``"gtsam"`` (:func:`mmsnap_graph.fusion.solvers.gtsam_graph.fuse_frame`, one factor graph per
frame); with pose covariances (:class:`~mmsnap_graph.fusion.options.NetworkCalibration`)
their covariances differ by a few percent
(docs/CONVENTIONS.md, "Calibration-aware fusion").

The result can be stored in the recording's HDF5 file as a ``/fused`` group
(:func:`mmsnap_graph.io.fused.write_fused`, :func:`mmsnap_graph.io.fused.read_fused`).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, replace
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
from ..solvers.vectorized import fuse_batch
from ..grid import grid_posterior
from ..problem import (
    check_node_noise,
    check_pose_covariances,
    check_prior,
    node_sigmas,
    valid_rows,
)
from .motion_check import apply_motion_check
from .rows import FusedRows
from ..robust import RESIDUAL_GATE_PROBABILITY
from ..options import (DEFAULT_OPTIONS, FusionOptions, NetworkCalibration, RobustOptions,
                       check_options, robust_options)
from ..solvers.settings import check_solver
from .timing import align_recording, offset_ranges
from ...data.noise import GaussianPrior, MeasurementNoise
from ...data.recording import Recording
from ...data.results import FusedSequence, Status
from ...errors import CalibrationError, MissingStepError, MmsnapError, ValidationError
from ..._validation import as_float_array, check_finite, check_pose
from .split_check import SPLIT_MESSAGE, split_rows
from .regroup import merge_body_detections
from .coverage import detection_reach_m, uncovered_rows
from .room import DEFAULT_BODY_M
from ...tracking.person_ids import assign_person_ids

__all__ = [
    "RECORDING_SOLVERS",
    "FusedSequence",
    "fuse_recording",
    "recording_poses",
    "group_detections",
]

#: The default prior of :func:`fuse_recording` (the paper's), also accepted with ``mode="ml"``.
_PAPER_PRIOR = GaussianPrior()


# ----------------------------------------------------------------------------
# Poses
# ----------------------------------------------------------------------------


def recording_poses(
    recording: Recording, node_poses: Mapping[str, ArrayLike] | None = None
) -> NDArray:
    """(N, 3) poses of the recording's nodes, in its order: from ``node_poses``
    (e.g. :func:`load_calibration_poses`) when given, else the poses stored in
    the recording. A node without a pose raises :class:`CalibrationError`."""
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


def _progress(total: int, desc: str, progress: bool | None):
    from tqdm import tqdm  # deferred: only a progress bar needs it

    disable = (not sys.stderr.isatty()) if progress is None else not progress
    return tqdm(total=total, desc=desc, unit="frame", disable=disable)


#: The solvers of a recording (:data:`~mmsnap_graph.fusion.solvers.settings.SOLVERS`).
RECORDING_SOLVERS = ("vectorized", "gtsam")


def _check_options(recording, mode, options, prior, progress):
    """Validate :func:`fuse_recording`'s options; return the prior to use."""
    if progress is not None and not isinstance(progress, (bool, np.bool_)):
        raise ValidationError(f"progress must be True, False or None, got {progress!r}")
    if mode not in ("map", "ml"):
        raise ValidationError(f"mode must be 'map' or 'ml', got {mode!r}")
    options = check_options(options)
    check_solver(options.solver, RECORDING_SOLVERS, what="options.solver")
    if options.covariance not in ("laplace", "grid"):
        raise ValidationError(f"options.covariance must be 'laplace' or 'grid' for a recording, "
                              f"got {options.covariance!r}")
    if not isinstance(recording, Recording):
        raise ValidationError(f"recording must be a Recording, got {type(recording).__name__}")
    check_prior(prior)
    if mode == "map" and prior is None:
        raise ValidationError("mode='map' needs a prior; pass a GaussianPrior or mode='ml'")
    if mode == "ml":
        if prior is not None and prior is not _PAPER_PRIOR:
            raise ValidationError("mode='ml' takes no prior; pass prior=None")
        prior = None
    return prior


def _node_options(recording, noise, pose_covariances, covariance):
    """``(noise per node (tuple), pose covariances (N, 3, 3) or None)`` in the
    recording's node order; a node missing from ``pose_covariances`` has an
    exact pose."""
    names = tuple(recording.node_names)
    noise = check_node_noise(noise, len(names), names)
    if pose_covariances is not None and not isinstance(pose_covariances, Mapping):
        raise ValidationError(
            "pose_covariances must be a mapping {node name: (3, 3) covariance}, got "
            f"{type(pose_covariances).__name__}")
    pose_cov = check_pose_covariances(pose_covariances, len(names), names)
    if covariance == "grid" and (pose_cov is not None or noise.count(noise[0]) != len(noise)):
        raise ValidationError(
            "covariance='grid' takes one noise for every node and exact poses; per-node noise "
            "and pose_covariances need covariance='laplace'")
    return noise, pose_cov


def _fuse_vectorized_rows(out: FusedRows, poses, z, obs, noise, prior, options, bar,
                          robust=None, pose_cov=None) -> None:
    k, block_rows = z.shape[0], options.block_rows
    # A row with an invalid observed measurement (range 0, say) is flagged,
    # not fused: fuse_batch would refuse the whole block.
    invalid = (obs & ~valid_rows(z)).any(axis=1)
    for start in range(0, k, block_rows):
        sl = np.arange(start, min(k, start + block_rows))
        sl = sl[~invalid[sl]]
        if sl.size:
            res = fuse_batch(poses, z[sl], observed=obs[sl], noise=noise, prior=prior,
                             pose_covariances=pose_cov, robust=robust, options=options)
            out.put(sl, res)
        bar.update(min(k, start + block_rows) - start)
    out.flag(invalid, Status.NON_FINITE,
             "a measurement is out of range (range <= 0, |omega| > pi or not finite)")


def _fuse_gtsam_rows(out: FusedRows, poses, z, obs, noise, prior, options, bar, robust=None,
                     pose_cov=None) -> None:
    from ..solvers.gtsam_graph import fuse_frame  # deferred: keeps GTSAM out of the vectorized path

    for i in range(z.shape[0]):
        try:
            r = fuse_frame(poses, z[i], observed=obs[i], noise=noise, prior=prior,
                           pose_covariances=pose_cov, robust=robust, options=options)
        except MmsnapError as exc:  # e.g. an initial position on a node
            out.flag(i, Status.NON_FINITE, f"{type(exc).__name__}: {exc}")
        else:
            out.put(i, r, message=r.message)
        bar.update(1)


def _merge_option(options, robust) -> float | None:
    """The width of one body to merge a node's centroids within (None: off)."""
    merge = robust is not None if options.body_merge is None else bool(options.body_merge)
    return options.merge_body_m if merge else None


def _motion_option(motion_check, robust) -> bool:
    """``motion_check`` (validated by FusionOptions); None: on with a ``robust`` option."""
    if motion_check is None:
        return robust is not None
    return bool(motion_check)


def _check_motion(out: FusedRows, groups, recording, poses, noise, prior, pose_cov,
                  options) -> None:
    """The motion check of :func:`fuse_recording` (hypotheses fitted by
    ``fuse_batch``; with the GTSAM solver the rows it refits are fitted
    again by ``fuse_frame`` from its solution)."""
    z = groups.measurements
    obs = groups.detection_index >= 0

    def refit(rows, mask, x0):
        return fuse_batch(poses, z[rows], observed=mask, noise=noise, prior=prior,
                          initial_state=x0, pose_covariances=pose_cov, options=options)

    done = apply_motion_check(out, groups.frame, obs, obs & valid_rows(z),
                              frame_period_s=recording.frame_period_s, refit=refit,
                              node_names=recording.node_names,
                              residual_gate_probability=RESIDUAL_GATE_PROBABILITY)
    if options.solver == "gtsam" and done.size:
        from ..solvers.gtsam_graph import fuse_frame  # deferred: keeps GTSAM out of the vectorized path

        for i in done:
            r = fuse_frame(poses, z[i], observed=obs[i] & ~out.rejected[i], noise=noise,
                           prior=prior, initial_state=out.state[i], pose_covariances=pose_cov,
                           options=options)
            out.put(i, r, rejected=out.rejected[i],
                    message=out.message[i] if r.success else r.message)


def _grid_covariances(out: FusedRows, poses, z, obs, noise, prior, points, progress) -> NDArray:
    """The grid covariance of every converged row (a failure flags the row)."""
    chosen = out.covariance.copy()
    rows = np.flatnonzero(out.status == Status.OK)
    with _progress(rows.size, "grid covariance", progress) as bar:
        for i in rows:
            try:
                grid = grid_posterior(out.state[i], poses, z[i], observed=obs[i], noise=noise[0],
                                      prior=prior, scale_covariance=out.covariance[i],
                                      points_per_axis=points)
                chosen[i] = grid.covariance
                if grid.message:
                    out.message[i] = f"{out.message[i]}; {grid.message}"
            except MmsnapError as exc:
                chosen[i] = np.nan
                out.flag(i, Status.GRID_FAILED, f"grid covariance failed: {exc}",
                         keep_covariance=True)
            bar.update(1)
    return chosen


def _screen_rows(out: FusedRows, groups, recording, poses, noise, prior, pose_cov, options,
                 motion_check) -> None:
    """The recording-level screens of the fused rows, in place: the motion
    check (docs/ROBUST.md), then the one-node rows of frames the association
    split (:mod:`.split_check`; after the motion check, the only row of a
    frame it kept stays)."""
    if motion_check:
        _check_motion(out, groups, recording, poses, noise, prior, pose_cov, options)
    split = split_rows(groups.frame, groups.detection_index, out.status,
                       keep_sole=bool(motion_check))
    # The estimate and its covariance stay for whoever wants them, untrusted.
    out.flag(split, Status.RESIDUAL_TEST_FAILED, SPLIT_MESSAGE, keep_covariance=True)
    if motion_check and options.coverage_check:
        reach_m = np.array([options.coverage_reach_m[n] for n in recording.node_names])
        _check_coverage(out, groups, recording, poses, reach_m)


def _coverage_reach(recording, options) -> dict[str, float]:
    """How far each node looks: ``options.coverage_reach_m``, else the
    farthest of its detections in ``recording`` (taken before the clock and
    range offsets move them, as a file's reader takes them)."""
    given = options.coverage_reach_m or {}
    return {n: given[n] if n in given else detection_reach_m(recording.nodes[n])
            for n in recording.node_names}


def _check_coverage(out: FusedRows, groups, recording, poses, reach_m) -> None:
    """The coverage check (:mod:`.coverage`): flag the rows a node that
    covers them never sees."""
    obs = groups.detection_index >= 0
    flag, node = uncovered_rows(groups.frame, out.state, out.status == Status.OK, obs,
                                groups.measurements[:, :, 0], poses,
                                frame_period_s=recording.frame_period_s, body_m=DEFAULT_BODY_M,
                                reach_m=reach_m)
    for r in np.flatnonzero(flag):
        out.flag(r, Status.MOTION_INCONSISTENT,
                 f"motion check: node {recording.node_names[node[r]]} covers this place and "
                 "does not see the target in the frames around (a multipath image or a ghost)",
                 rejected=obs[r])


def _calibrated_centroids(recording, time_offset_s, range_offset_m, options):
    """The centroids on the reference clock and with the range offset
    added (the calibration's), as :func:`fuse_recording` fuses them."""
    if time_offset_s:
        if options.source != "centroids":
            raise ValidationError("calibration.time_offset_s aligns the centroids: use "
                                  "source='centroids'")
        recording = align_recording(recording, time_offset_s)
    if range_offset_m is not None:
        if options.source != "centroids":
            raise ValidationError("calibration.range_offset_m moves the centroids' ranges: use "
                                  "source='centroids'")
        recording = offset_ranges(recording, range_offset_m)
    return recording


def fuse_recording(
    recording: Recording,
    *,
    calibration: NetworkCalibration | None = None,
    mode: Literal["map", "ml"] = "map",
    noise: MeasurementNoise | Mapping[str, MeasurementNoise] = MeasurementNoise(),
    prior: GaussianPrior | None = _PAPER_PRIOR,
    robust: RobustOptions | Literal["gate", "huber", "cauchy"] | None = None,
    options: FusionOptions = DEFAULT_OPTIONS,
    progress: bool | None = None,
) -> FusedSequence:
    """Fuse every target in every frame of ``recording``.

    Parameters
    ----------
    recording : Recording
        Its nodes' ``centroids`` (or ``point_cloud``) are fused.
    calibration : NetworkCalibration, optional
        The network's calibration (:class:`~mmsnap_graph.fusion.options.NetworkCalibration`;
        None: the poses stored in the recording, nothing else), its parts:
        ``node_poses`` (e.g. :func:`load_calibration_poses`) replace the
        recording's poses. ``pose_covariances``: calibration-aware fusion
        (docs/CONVENTIONS.md, "Calibration-aware fusion"): each node pose's
        covariance in the Pose2 body tangent (the calibration's marginals);
        a node left out (or all NaN / all zero) has an exact pose. The
        estimates do not change; ``covariance`` and ``laplace_covariance``
        include the poses'
        (:func:`~mmsnap_graph.fusion.solvers.vectorized.fuse_batch`,
        :func:`~mmsnap_graph.fusion.solvers.gtsam_graph.fuse_frame`). Needs
        ``options.covariance="laplace"``. ``time_offset_s``: each node's
        clock offset (node time + offset = reference time): the centroids are
        brought to the reference clock first
        (:func:`mmsnap_graph.fusion.recording.timing.align_recording`: whole
        frames, then the range by Doppler times the rest); a node left out
        keeps its clock. ``range_offset_m``: the calibration's range offset
        (``RecordingCalibration.range_offset_m``, an extended target's
        reflection depth), added to every centroid's range first
        (:func:`~mmsnap_graph.fusion.recording.timing.offset_ranges`), so
        that the fused state is the body's centre; its uncertainty is not in
        the fused covariances.
    mode : ``"map"`` (Bayesian, with ``prior``) or ``"ml"`` (no prior: pass
        ``prior=None`` or leave the default).
    noise : MeasurementNoise (every node; default the paper's) or a mapping
        ``{node name: MeasurementNoise}`` holding every fused node (per-node
        noise, docs/CONVENTIONS.md); used by the association and the fusion.
    prior : GaussianPrior for MAP, default the paper's.
    robust : RobustOptions, "gate", "huber", "cauchy" or None
        Robust one-shot fusion (:mod:`mmsnap_graph.fusion.robust`; default
        None): ``"gate"`` leaves out a node whose residual fails the
        chi-square gate (``FusedSequence.rejected``), ``"huber"`` /
        ``"cauchy"`` down-weight it.
    options : FusionOptions
        ``solver``: ``"vectorized"`` (the default) or ``"gtsam"`` (per-frame
        factor graphs); ``covariance``: ``"laplace"`` or ``"grid"`` (the
        paper's numerical posterior covariance,
        :func:`mmsnap_graph.fusion.grid.grid_posterior`, laid out along the
        Laplace covariance; slow: ``grid_points_per_axis^4`` points per
        frame); ``gate_probability``: the association gate (see
        :mod:`mmsnap_graph.fusion.association`); ``source``: which detections
        to fuse; ``block_rows``: rows per call of the vectorized solver (the
        progress bar advances per block); ``motion_check``: check each row
        against its neighbouring frames' motion
        (:mod:`~mmsnap_graph.fusion.recording.motion_check`, docs/ROBUST.md):
        refit it without the nodes that disagree, or flag it (a ghost, an
        ambiguous frame); None (the default): on with a ``robust`` option.
        ``body_merge``, ``merge_body_m``, ``coverage_check``: docs/ROBUST.md.
        ``lm`` and the vectorized solver's settings as in ``fuse_batch``.
    progress : show a tqdm bar (default: when stderr is a terminal).
    The rows' ``track_id``: :func:`~mmsnap_graph.tracking.person_ids.assign_person_ids`.
    """
    cal = NetworkCalibration() if calibration is None else calibration
    if not isinstance(cal, NetworkCalibration):
        raise ValidationError(f"calibration must be a NetworkCalibration, got "
                              f"{type(cal).__name__}")
    prior = _check_options(recording, mode, options, prior, progress)
    options = replace(options, coverage_reach_m=_coverage_reach(recording, options))
    recording = _calibrated_centroids(recording, cal.time_offset_s, cal.range_offset_m, options)
    noise, pose_cov = _node_options(recording, noise, cal.pose_covariances, options.covariance)
    robust = robust_options(robust)
    motion_check = _motion_option(options.motion_check, robust)
    poses = recording_poses(recording, cal.node_poses)
    groups = group_detections(recording, poses, noise, gate_probability=options.gate_probability,
                              source=options.source, merge_body_m=_merge_option(options, robust))
    obs = groups.detection_index >= 0
    z = groups.measurements
    out = FusedRows(groups.frame.size, obs.shape[1])
    solve = replace(options, covariance="laplace")  # the grid one comes after the checks
    with _progress(z.shape[0], f"fuse ({options.solver}, {mode})", progress) as bar:
        fuse_rows = _fuse_vectorized_rows if options.solver == "vectorized" else _fuse_gtsam_rows
        fuse_rows(out, poses, z, obs, noise, prior, solve, bar, robust, pose_cov)
    _screen_rows(out, groups, recording, poses, noise, prior, pose_cov, solve, motion_check)
    chosen = out.covariance.copy()
    if options.covariance == "grid":  # the grid posterior of the measurements kept
        gate = robust is not None and robust.kernel == "gate"
        kept = obs & ~out.rejected if (gate or motion_check) else obs
        chosen = _grid_covariances(out, poses, z, kept, noise, prior, options.grid_points_per_axis,
                                   progress)
    return assign_person_ids(_sequence(recording, poses, groups, out, chosen, mode=mode,
                                       options=options, noise=noise, prior=prior, robust=robust))


def _sequence(recording, poses, groups, out, chosen, *, mode, options, noise, prior,
              robust) -> FusedSequence:
    """The :class:`FusedSequence` of :func:`fuse_recording`."""
    obs = groups.detection_index >= 0
    return FusedSequence(
        node_names=tuple(recording.node_names),
        node_poses=poses,
        mode=mode,
        covariance_method=options.covariance,
        solver=options.solver,
        frame=groups.frame,
        target=groups.target,
        label=groups.label,
        detection_index=groups.detection_index,
        observed=obs,
        state=out.state,
        covariance=chosen,
        laplace_covariance=out.covariance,
        success=out.status == Status.OK,
        status=out.status,
        message=out.message,
        iterations=out.iterations,
        final_cost=out.final_cost,
        degeneracy=out.degeneracy,
        # (3,) for one noise, (N, 3) (node order) for per-node noise.
        noise_sigmas=(np.asarray(noise[0].sigmas, dtype=float)
                      if noise.count(noise[0]) == len(noise) else node_sigmas(noise)),
        prior_mean=None if prior is None else np.asarray(prior.mean, dtype=float),
        prior_sigmas=None if prior is None else np.asarray(prior.sigmas, dtype=float),
        gate_probability=options.gate_probability,
        rejected=out.rejected,
        robust=None if robust is None else robust.kernel,
        frame_period_s=recording.frame_period_s,
        time_origin_s=_time_origin(recording.metadata),
    )


def _time_origin(metadata) -> float | None:
    """The recording's wall-clock origin (Unix seconds of time 0), if valid."""
    try:
        value = float(metadata.get("time_origin_s"))
    except (AttributeError, TypeError, ValueError):
        return None
    return value if np.isfinite(value) else None
