"""One-shot fusion of a whole recording (paper Sec. III-B, frame after frame).

:func:`fuse_recording` takes every frame of a recording, groups the nodes'
centroids into targets (:mod:`mmsnap_graph.fusion.association`), and fuses each group
with the calibrated node poses: MAP (the paper's Bayesian estimate) or ML,
with the Laplace covariance or the paper's grid covariance. A frame where only
some nodes see a target is fused with the nodes that do; a frame that cannot
be fused is flagged (``success`` False, a status and a message), never raised.

Two solvers give the same answers (``tests/test_fuse_agreement.py``):
``"batch"`` (:func:`mmsnap_graph.fusion.batch.fuse_batch`, vectorized over frames)
and ``"gtsam"`` (:func:`mmsnap_graph.fusion.oneshot.fuse_frame`, one factor graph per
frame).

The result can be stored in the recording's HDF5 file as a ``/fused`` group
(:func:`write_fused`, :func:`read_fused`; layout in :data:`FUSED_LAYOUT`).
"""

from __future__ import annotations

import json
import os
import shutil
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Literal, Mapping

import numpy as np
from numpy.typing import ArrayLike, NDArray

from factors.models import detection_to_global

from .association import associate_frame, detection_position_covariance, gate_threshold
from .batch import STATUS_MESSAGES, fuse_batch
from .._atomic import atomic_path
from ..errors import CalibrationError, FileFormatError, MmsnapError, ValidationError
from ..data.recording import Recording
from .._validation import as_float_array, check_finite

__all__ = [
    "FUSED_GROUP",
    "FUSED_LAYOUT",
    "FusedSequence",
    "fuse_recording",
    "recording_poses",
    "group_detections",
    "write_fused",
    "read_fused",
]

#: Name of the HDF5 group written by :func:`write_fused`.
FUSED_GROUP = "fused"
_FUSED_VERSION = "1.0"

#: The ``/fused`` group, for docs/FORMAT.md. K rows = one per fused target per frame.
FUSED_LAYOUT = """\
/fused                 attrs: format_version = "1.0", mode = "map" | "ml",
                              covariance_method = "laplace" | "grid",
                              solver = "batch" | "gtsam",
                              node_order (str array, N), node_poses (N, 3) [x_m, y_m, phi_rad],
                              noise_sigmas (3,) [range_m, omega_rad, doppler_mps],
                              prior_mean (4,), prior_sigmas (4,) (MAP only),
                              gate_probability, status_messages (JSON: code -> text)
    frame              (K,) int64     frame number
    target             (K,) int64     index of the target within its frame (association order)
    label              (K,) int64     the centroids' target_id when all members agree, else -1
    detection_index    (K, N) int64   row of each node's centroids used, -1 = node did not see it
    observed           (K, N) bool    detection_index >= 0
    x_m, y_m, vx_mps, vy_mps (K,) float64   fused state, global frame (S1's)
    covariance         (K, 4, 4) float64   the chosen covariance (Laplace or grid), NaN if failed
    laplace_covariance (K, 4, 4) float64   always the Laplace covariance
    success            (K,) bool
    status             (K,) int8      0 converged, 1 max iterations, 2 singular information,
                                      3 non-finite, 4 no measurement and no prior, 5 grid failed
    message            (K,) str
    iterations         (K,) int64;  final_cost (K,) float64 (0.5 sum of squared whitened
                                    residuals, prior included);  degeneracy (K,) float64
"""

_STATUS = dict(STATUS_MESSAGES)
_GRID_FAILED = 5
_STATUS[_GRID_FAILED] = "grid covariance failed"


@dataclass(frozen=True, kw_only=True, slots=True)
class FusedSequence:
    """One-shot estimates of every target in every frame of a recording.

    K rows, one per fused target per frame, sorted by frame then target.

    node_names : (N,) names, in the recording's order; node_poses : (N, 3).
    mode : ``"map"`` or ``"ml"``; covariance_method : ``"laplace"`` or ``"grid"``;
    solver : ``"batch"`` or ``"gtsam"``.
    frame, target, label : (K,) int (see :data:`FUSED_LAYOUT`).
    detection_index : (K, N) int; observed : (K, N) bool.
    state : (K, 4) ``(x_m, y_m, vx_mps, vy_mps)``; covariance : (K, 4, 4) the
    chosen covariance; laplace_covariance : (K, 4, 4).
    success : (K,) bool; status : (K,) int; message : (K,) str (object array).
    iterations : (K,) int; final_cost, degeneracy : (K,) float.
    noise_sigmas : (3,); prior_mean, prior_sigmas : (4,) or None (ML);
    gate_probability : float.
    """

    node_names: tuple
    node_poses: NDArray
    mode: str
    covariance_method: str
    solver: str
    frame: NDArray
    target: NDArray
    label: NDArray
    detection_index: NDArray
    observed: NDArray
    state: NDArray
    covariance: NDArray
    laplace_covariance: NDArray
    success: NDArray
    status: NDArray
    message: NDArray
    iterations: NDArray
    final_cost: NDArray
    degeneracy: NDArray
    noise_sigmas: NDArray
    prior_mean: NDArray | None
    prior_sigmas: NDArray | None
    gate_probability: float

    def __len__(self) -> int:
        return int(self.frame.shape[0])

    def rows_of_label(self, label: int) -> NDArray:
        """Row indices of one labelled target, in frame order."""
        rows = np.flatnonzero(self.label == label)
        return rows[np.argsort(self.frame[rows], kind="stable")]


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
                raise CalibrationError(
                    f"node {name!r} has no pose in the recording; calibrate it or pass calibration poses"
                )
        arr = check_finite(as_float_array(pose, f"pose of {name}"), f"pose of {name}")
        if arr.shape != (3,):
            raise ValidationError(f"pose of {name} must have shape (3,), got {arr.shape}")
        out.append(arr)
    return np.stack(out)


# ----------------------------------------------------------------------------
# Grouping the centroids into targets
# ----------------------------------------------------------------------------


@dataclass(frozen=True, kw_only=True, slots=True)
class _Groups:
    frame: NDArray  # (K,)
    target: NDArray  # (K,)
    label: NDArray  # (K,)
    detection_index: NDArray  # (K, N)
    measurements: NDArray  # (K, N, 3), zeros where unobserved


def group_detections(
    recording: Recording,
    node_poses: ArrayLike,
    sigmas: ArrayLike,
    *,
    gate_probability: float = 0.999,
    source: Literal["centroids", "point_cloud"] = "centroids",
) -> _Groups:
    """Group every frame's detections into targets (see
    :mod:`mmsnap_graph.fusion.association`). Returns arrays of K groups sorted by
    frame then target: ``frame, target, label, detection_index (K, N),
    measurements (K, N, 3)``.

    Frames where every node has at most one detection and all of them fall in
    one gate are grouped in a vectorized pass; the others go through
    :func:`~mmsnap_graph.fusion.association.associate_frame` one by one (identical
    results).
    """
    poses = np.asarray(node_poses, dtype=float)
    names = recording.node_names
    n_nodes = len(names)
    gate = gate_threshold(gate_probability)
    dets = [getattr(recording.nodes[name], source) for name in names]
    if all(d is None or len(d) == 0 for d in dets):
        raise ValidationError(f"no node of the recording has {source}; nothing to fuse")
    meas = [None if d is None else d.measurements for d in dets]
    frames_of = [np.zeros(0, np.int64) if d is None else d.frame for d in dets]
    all_frames = np.unique(np.concatenate(frames_of))
    n_f = all_frames.size
    # Per node: the detection rows of each frame, as (start, count) in frame order.
    order = [np.argsort(f, kind="stable") for f in frames_of]
    counts = np.zeros((n_f, n_nodes), dtype=np.int64)
    starts = np.zeros((n_f, n_nodes), dtype=np.int64)
    for n in range(n_nodes):
        fr = frames_of[n][order[n]]
        pos = np.searchsorted(all_frames, fr)
        c = np.bincount(pos, minlength=n_f)
        counts[:, n] = c
        starts[:, n] = np.concatenate([[0], np.cumsum(c)[:-1]])

    # Vectorized pass: at most one detection per node, all inside one gate.
    single = np.all(counts <= 1, axis=1)
    first_row = np.full((n_f, n_nodes), -1, dtype=np.int64)
    for n in range(n_nodes):
        has = counts[:, n] == 1
        first_row[has, n] = order[n][starts[has, n]]
    info = np.zeros((n_f, 2, 2))
    eta = np.zeros((n_f, 2))
    joint_ok = single.copy()
    for n in range(n_nodes):
        rows = first_row[:, n]
        has = single & (rows >= 0)
        if not np.any(has):
            continue
        z = meas[n][rows[has]]
        p = detection_to_global(z[:, 0], z[:, 1], poses[n])
        c = detection_position_covariance(z[:, 0], z[:, 1], poses[n], sigmas)
        ic = np.linalg.inv(c)
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

    frame_l, target_l, index_l = [], [], []
    fast = np.flatnonzero(joint_ok & np.any(first_row >= 0, axis=1))
    frame_l.append(all_frames[fast])
    target_l.append(np.zeros(fast.size, dtype=np.int64))
    index_l.append(first_row[fast])
    for fi in np.flatnonzero(~joint_ok):
        rows_n = [order[n][starts[fi, n]:starts[fi, n] + counts[fi, n]] for n in range(n_nodes)]
        per_node = [meas[n][r] if r.size else np.zeros((0, 3)) for n, r in enumerate(rows_n)]
        assoc = associate_frame(per_node, poses, sigmas, gate_probability=gate_probability)
        g = len(assoc)
        idx = np.full((g, n_nodes), -1, dtype=np.int64)
        for n in range(n_nodes):
            m = assoc.members[:, n] >= 0
            idx[m, n] = rows_n[n][assoc.members[m, n]]
        frame_l.append(np.full(g, all_frames[fi]))
        target_l.append(np.arange(g, dtype=np.int64))
        index_l.append(idx)
    frame = np.concatenate(frame_l)
    target = np.concatenate(target_l)
    index = np.concatenate(index_l)
    srt = np.lexsort((target, frame))
    frame, target, index = frame[srt], target[srt], index[srt]

    k = frame.size
    z = np.zeros((k, n_nodes, 3))
    labels = np.full((k, n_nodes), -1, dtype=np.int64)
    for n in range(n_nodes):
        has = index[:, n] >= 0
        if np.any(has):
            z[has, n] = meas[n][index[has, n]]
            if dets[n].target_id is not None:
                labels[has, n] = dets[n].target_id[index[has, n]]
    obs = index >= 0
    lab = np.where(obs, labels, np.iinfo(np.int64).max).min(axis=1)
    agree = np.all(~obs | (labels == lab[:, None]), axis=1) & (lab >= 0) & obs.any(axis=1)
    label = np.where(agree, lab, -1)
    return _Groups(frame=frame, target=target, label=label, detection_index=index, measurements=z)


# ----------------------------------------------------------------------------
# Fusion
# ----------------------------------------------------------------------------


def _progress(total: int, desc: str, progress: bool | None):
    from tqdm import tqdm

    disable = (not sys.stderr.isatty()) if progress is None else not progress
    return tqdm(total=total, desc=desc, unit="frame", disable=disable)


def fuse_recording(
    recording: Recording,
    *,
    node_poses: Mapping[str, ArrayLike] | None = None,
    mode: Literal["map", "ml"] = "map",
    covariance: Literal["laplace", "grid"] = "laplace",
    solver: Literal["batch", "gtsam"] = "batch",
    noise=None,
    prior=None,
    gate_probability: float = 0.999,
    source: Literal["centroids", "point_cloud"] = "centroids",
    grid_points_per_axis: int = 21,
    block_rows: int = 65536,
    progress: bool | None = None,
) -> FusedSequence:
    """Fuse every target in every frame of ``recording``.

    Parameters
    ----------
    recording : Recording
        Its nodes' ``centroids`` (or ``point_cloud``) are fused.
    node_poses : mapping name -> (3,), optional
        Calibrated poses (:func:`load_calibration_poses`); default: the poses
        stored in the recording.
    mode : ``"map"`` (Bayesian, with ``prior``) or ``"ml"``.
    covariance : ``"laplace"`` or ``"grid"`` (the paper's numerical posterior
        covariance, :func:`mmsnap_graph.fusion.grid.grid_posterior`, laid out
        along the Laplace covariance; slow: ``grid_points_per_axis^4`` points
        per frame).
    solver : ``"batch"`` (vectorized) or ``"gtsam"`` (per-frame factor graphs).
    noise : MeasurementNoise, default the paper's. prior : GaussianPrior for
        MAP, default the paper's.
    gate_probability : association gate (see :mod:`mmsnap_graph.fusion.association`).
    source : which detections to fuse.
    block_rows : rows per batch call (the progress bar advances per block).
    progress : show a tqdm bar (default: when stderr is a terminal).
    """
    from .oneshot import GaussianPrior, MeasurementNoise

    if mode not in ("map", "ml"):
        raise ValidationError(f"mode must be 'map' or 'ml', got {mode!r}")
    if covariance not in ("laplace", "grid"):
        raise ValidationError(f"covariance must be 'laplace' or 'grid', got {covariance!r}")
    if solver not in ("batch", "gtsam"):
        raise ValidationError(f"solver must be 'batch' or 'gtsam', got {solver!r}")
    if source not in ("centroids", "point_cloud"):
        raise ValidationError(f"source must be 'centroids' or 'point_cloud', got {source!r}")
    if not isinstance(recording, Recording):
        raise ValidationError(f"recording must be a Recording, got {type(recording).__name__}")
    if int(block_rows) < 1:
        raise ValidationError(f"block_rows must be >= 1, got {block_rows!r}")
    noise = MeasurementNoise() if noise is None else noise
    if mode == "map":
        prior = GaussianPrior() if prior is None else prior
    elif prior is not None:
        raise ValidationError("mode='ml' takes no prior; pass prior=None")
    poses = recording_poses(recording, node_poses)
    groups = group_detections(recording, poses, noise.sigmas, gate_probability=gate_probability,
                              source=source)
    k = groups.frame.size
    obs = groups.detection_index >= 0
    z = groups.measurements

    state = np.full((k, 4), np.nan)
    lap = np.full((k, 4, 4), np.nan)
    status = np.zeros(k, dtype=np.int8)
    message = np.empty(k, dtype=object)
    iterations = np.zeros(k, dtype=np.int64)
    cost = np.full(k, np.nan)
    degeneracy = np.full(k, np.inf)
    with _progress(k, f"fuse ({solver}, {mode})", progress) as bar:
        if solver == "batch":
            for start in range(0, k, int(block_rows)):
                sl = slice(start, min(k, start + int(block_rows)))
                res = fuse_batch(poses, z[sl], observed=obs[sl], noise=noise, prior=prior)
                state[sl], lap[sl], status[sl] = res.state, res.covariance, res.status
                iterations[sl], cost[sl], degeneracy[sl] = res.iterations, res.final_cost, res.degeneracy
                bar.update(sl.stop - sl.start)
            texts = np.array([_STATUS[c] for c in range(len(_STATUS))], dtype=object)
            message[:] = texts[status]
        else:
            from .oneshot import fuse_frame

            for i in range(k):
                try:
                    r = fuse_frame(poses, z[i], observed=obs[i], noise=noise, prior=prior)
                except MmsnapError as exc:  # e.g. an initial position on a node
                    status[i], message[i] = 3, f"{type(exc).__name__}: {exc}"
                else:
                    state[i], lap[i], iterations[i], cost[i] = r.state, r.covariance, r.iterations, r.final_cost
                    degeneracy[i] = r.degeneracy
                    message[i] = r.message
                    status[i] = 0 if r.success else _gtsam_status(r.message)
                bar.update(1)
    chosen = lap.copy()
    if covariance == "grid":
        from .grid import grid_posterior

        rows = np.flatnonzero(status == 0)
        with _progress(rows.size, "grid covariance", progress) as bar:
            for i in rows:
                try:
                    grid = grid_posterior(state[i], poses, z[i], observed=obs[i], noise=noise,
                                          prior=prior, scale_covariance=lap[i],
                                          points_per_axis=grid_points_per_axis)
                    chosen[i] = grid.covariance
                    if grid.message:
                        message[i] = f"{message[i]}; {grid.message}"
                except MmsnapError as exc:
                    chosen[i] = np.nan
                    status[i] = _GRID_FAILED
                    message[i] = f"grid covariance failed: {exc}"
                bar.update(1)
    success = status == 0
    return FusedSequence(
        node_names=tuple(recording.node_names),
        node_poses=poses,
        mode=mode,
        covariance_method=covariance,
        solver=solver,
        frame=groups.frame,
        target=groups.target,
        label=groups.label,
        detection_index=groups.detection_index,
        observed=obs,
        state=state,
        covariance=chosen,
        laplace_covariance=lap,
        success=success,
        status=status,
        message=message,
        iterations=iterations,
        final_cost=cost,
        degeneracy=degeneracy,
        noise_sigmas=np.asarray(noise.sigmas, dtype=float),
        prior_mean=None if prior is None else np.asarray(prior.mean, dtype=float),
        prior_sigmas=None if prior is None else np.asarray(prior.sigmas, dtype=float),
        gate_probability=float(gate_probability),
    )


def _gtsam_status(text: str) -> int:
    """Map a failed :class:`FusionResult`'s message to a status code."""
    if "max_iterations" in text:
        return 1
    if "indeterminate" in text or "positive definite" in text:
        return 2
    if "no node observed" in text:
        return 4
    return 3


# ----------------------------------------------------------------------------
# HDF5 /fused group
# ----------------------------------------------------------------------------

_STATE_NAMES = ("x_m", "y_m", "vx_mps", "vy_mps")


def _fill_group(g, fused: FusedSequence) -> None:
    import h5py

    g.attrs["format_version"] = _FUSED_VERSION
    g.attrs["mode"] = fused.mode
    g.attrs["covariance_method"] = fused.covariance_method
    g.attrs["solver"] = fused.solver
    g.attrs.create("node_order", np.array(fused.node_names, dtype=object),
                   dtype=h5py.string_dtype(encoding="utf-8"))
    g.attrs["node_poses"] = fused.node_poses
    g.attrs["noise_sigmas"] = fused.noise_sigmas
    if fused.prior_mean is not None:
        g.attrs["prior_mean"] = fused.prior_mean
        g.attrs["prior_sigmas"] = fused.prior_sigmas
    g.attrs["gate_probability"] = fused.gate_probability
    g.attrs["status_messages"] = json.dumps({str(k): v for k, v in _STATUS.items()})
    big = fused.frame.size >= 1024
    kw = dict(compression="gzip", compression_opts=1) if big else {}

    def put(name, data, dtype=None):
        g.create_dataset(name, data=np.asarray(data, dtype=dtype), **kw)

    put("frame", fused.frame, np.int64)
    put("target", fused.target, np.int64)
    put("label", fused.label, np.int64)
    put("detection_index", fused.detection_index, np.int64)
    put("observed", fused.observed, bool)
    for i, name in enumerate(_STATE_NAMES):
        put(name, fused.state[:, i], np.float64)
    put("covariance", fused.covariance, np.float64)
    put("laplace_covariance", fused.laplace_covariance, np.float64)
    put("success", fused.success, bool)
    put("status", fused.status, np.int8)
    g.create_dataset("message", data=np.array([str(m) for m in fused.message], dtype=object),
                     dtype=h5py.string_dtype(encoding="utf-8"))
    put("iterations", fused.iterations, np.int64)
    put("final_cost", fused.final_cost, np.float64)
    put("degeneracy", fused.degeneracy, np.float64)


def write_fused(path: str | os.PathLike, fused: FusedSequence, *,
                output: str | os.PathLike | None = None) -> Path:
    """Store ``fused`` as the ``/fused`` group of the recording at ``path``
    (replacing an existing one), or of a copy of it at ``output``.

    Atomic: the file is copied to a temporary file in the target's folder,
    the group written there, and the copy moved over the target
    (:func:`mmsnap_graph._atomic.atomic_path`). Returns the path written.
    """
    import h5py

    src = Path(path)
    if not src.exists():
        raise FileFormatError(f"{src} does not exist")
    dst = src if output is None else Path(output)
    with atomic_path(dst) as tmp:
        shutil.copyfile(src, tmp)
        try:
            f = h5py.File(tmp, "r+")
        except OSError as exc:
            raise FileFormatError(f"{src} is not a writable HDF5 file: {exc}") from exc
        with f:
            if FUSED_GROUP in f:
                del f[FUSED_GROUP]
            _fill_group(f.create_group(FUSED_GROUP), fused)
    return dst


def read_fused(path: str | os.PathLike) -> FusedSequence:
    """Read the ``/fused`` group written by :func:`write_fused`; a missing
    group, dataset or attribute raises :class:`FileFormatError` naming it."""
    import h5py

    p = Path(path)
    if not p.exists():
        raise FileFormatError(f"{p} does not exist")
    with h5py.File(p, "r") as f:
        if FUSED_GROUP not in f:
            raise FileFormatError(f"{p} has no /{FUSED_GROUP} group; run `mmsnap fuse` first")
        g = f[FUSED_GROUP]

        def ds(name):
            if name not in g:
                raise FileFormatError(f"{p}: /{FUSED_GROUP}/{name} is missing")
            return g[name][()]

        def attr(name, required=True):
            if name not in g.attrs:
                if required:
                    raise FileFormatError(f"{p}: attribute /{FUSED_GROUP}.{name} is missing")
                return None
            return g.attrs[name]

        names = tuple(str(n.decode() if isinstance(n, bytes) else n) for n in attr("node_order"))
        prior_mean = attr("prior_mean", required=False)
        prior_sigmas = attr("prior_sigmas", required=False)
        msgs = ds("message")
        state = np.stack([ds(n) for n in _STATE_NAMES], axis=-1)

        def text(v):
            return v.decode() if isinstance(v, bytes) else str(v)

        out = FusedSequence(
            node_names=names,
            node_poses=np.asarray(attr("node_poses"), dtype=float),
            mode=text(attr("mode")),
            covariance_method=text(attr("covariance_method")),
            solver=text(attr("solver")),
            frame=ds("frame"),
            target=ds("target"),
            label=ds("label"),
            detection_index=ds("detection_index"),
            observed=ds("observed").astype(bool),
            state=state,
            covariance=ds("covariance"),
            laplace_covariance=ds("laplace_covariance"),
            success=ds("success").astype(bool),
            status=ds("status"),
            message=np.array([text(m) for m in msgs], dtype=object),
            iterations=ds("iterations"),
            final_cost=ds("final_cost"),
            degeneracy=ds("degeneracy"),
            noise_sigmas=np.asarray(attr("noise_sigmas"), dtype=float),
            prior_mean=None if prior_mean is None else np.asarray(prior_mean, dtype=float),
            prior_sigmas=None if prior_sigmas is None else np.asarray(prior_sigmas, dtype=float),
            gate_probability=float(attr("gate_probability")),
        )
    k = out.frame.shape[0]
    n = len(out.node_names)
    if out.state.shape != (k, 4) or out.covariance.shape != (k, 4, 4) or out.observed.shape != (k, n):
        raise FileFormatError(f"{p}: /{FUSED_GROUP} datasets disagree in length (frame has {k} rows)")
    return out
