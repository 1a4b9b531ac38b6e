"""The ``/fused`` group of a recording file: one-shot estimates of every target
in every frame (:class:`~mmsnap_graph.data.results.FusedSequence`, made by
:func:`mmsnap_graph.fusion.recording.sequence.fuse_recording`).

:func:`write_fused` and :func:`read_fused` are a symmetric pair; the layout is
:data:`FUSED_LAYOUT` (quoted in docs/FORMAT.md). The ``status`` codes are those
of :class:`~mmsnap_graph.data.results.Status` 0 to 5 and 9 to 12 (:data:`FUSED_STATUSES`).
"""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path

import h5py
import numpy as np

from ..data.results import FusedSequence, Status
from ..errors import FileFormatError, MmsnapError
from .guard import H5_ERRORS, edited_copy, open_group, read_guard, replace_group
from .versions import check_format_version

__all__ = ["FUSED_GROUP", "FUSED_LAYOUT", "FUSED_STATUSES", "write_fused", "read_fused"]

#: Name of the HDF5 group written by :func:`write_fused`.
FUSED_GROUP = "fused"
_FUSED_VERSION = "1.2"

#: The ``/fused`` group, for docs/FORMAT.md (the tests check that it is quoted there). K rows = one per fused target per frame.
FUSED_LAYOUT = """\
/fused                 attrs: format_version = "1.2" (1.1: without track_id;
                              1.0: without time_s and information),
                              mode = "map" | "ml",
                              covariance_method = "laplace" | "grid",
                              solver = "vectorized" | "gtsam",
                              node_order (str array, N), node_poses (N, 3) [x_m, y_m, phi_rad],
                              noise_sigmas (3,) [range_m, omega_rad, doppler_mps],
                              prior_mean (4,), prior_sigmas (4,) (MAP only),
                              gate_probability, status_messages (JSON: code -> text),
                              robust = "gate" | "huber" | "cauchy" (only when robust fusion ran),
                              frame_period_s, time_origin_s (Unix s of time_s = 0; only when
                              the recording holds wall-clock time stamps),
                              consistency (JSON, written by `mmsnap fuse`: the covariances'
                              self-check without truth, docs/ROBUST.md "The self-check")
    frame              (K,) int64     frame number
    time_s             (K,) float64   seconds since the recording's start (frame * frame_period_s)
    target             (K,) int64     index of the target within its frame (association order)
    label              (K,) int64     the centroids' target_id when all members agree, else -1
    track_id           (K,) int64     person id: the central tracker's track that the row updated
                                      or started (docs/FORMAT.md, "Person ids"); -1 = the row was
                                      not fused successfully (optional; absent = not tracked)
    detection_index    (K, N) int64   row of each node's centroids used, -1 = node did not see it
    observed           (K, N) bool    detection_index >= 0
    x_m, y_m, vx_mps, vy_mps (K,) float64   fused state, global frame (S1's)
    covariance         (K, 4, 4) float64   the chosen covariance (Laplace or grid), NaN if failed
    laplace_covariance (K, 4, 4) float64   always the Laplace covariance
    information        (K, 4, 4) float64   prior-free measurement information Y (MAP:
                                           laplace_covariance^-1 - prior information;
                                           ML: laplace_covariance^-1); may be singular
    information_vector (K, 4) float64      y = laplace_covariance^-1 x - prior information m0
                                           (ML: Y x); Y^-1 y = the prior-free state
    success            (K,) bool
    status             (K,) int8      0 converged, 1 max iterations, 2 singular information,
                                      3 non-finite, 4 no measurement and no prior, 5 grid failed,
                                      9 residual test failed (robust fusion could not repair it),
                                      10 not consistent with the motion of any target in the
                                      neighbouring frames (the motion check, docs/ROBUST.md),
                                      11 outside the room bounds (mmsnap fuse --bounds),
                                      12 within a body's width of a better-supported target of
                                      its frame (docs/ROBUST.md)
    rejected           (K, N) bool    node left out / down-weighted by robust fusion (optional;
                                      absent = none)
    message            (K,) str
    iterations         (K,) int64;  final_cost (K,) float64 (0.5 sum of squared whitened
                                    residuals, prior included);  degeneracy (K,) float64
"""


#: The status codes a ``/fused`` group holds (its ``status_messages`` attribute).
FUSED_STATUSES = (Status.OK, Status.MAX_ITERATIONS, Status.SINGULAR, Status.NON_FINITE,
                  Status.NO_INFORMATION, Status.GRID_FAILED, Status.RESIDUAL_TEST_FAILED,
                  Status.MOTION_INCONSISTENT, Status.OUTSIDE_BOUNDS, Status.DUPLICATE)

_STATE_NAMES = ("x_m", "y_m", "vx_mps", "vy_mps")


def _fill_group(g, fused: FusedSequence) -> None:
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
    g.attrs["status_messages"] = json.dumps({str(int(s)): s.message for s in FUSED_STATUSES})
    if fused.robust is not None:
        g.attrs["robust"] = fused.robust
    if fused.frame_period_s is not None:
        g.attrs["frame_period_s"] = fused.frame_period_s
    if fused.time_origin_s is not None:
        g.attrs["time_origin_s"] = fused.time_origin_s
    big = fused.frame.size >= 1024
    kw = dict(compression="gzip", compression_opts=1) if big else {}

    def put(name, data, dtype=None):
        g.create_dataset(name, data=np.asarray(data, dtype=dtype), **kw)

    put("frame", fused.frame, np.int64)
    if fused.time_s is not None:
        put("time_s", fused.time_s, np.float64)
    put("target", fused.target, np.int64)
    put("label", fused.label, np.int64)
    if fused.track_id is not None:
        put("track_id", fused.track_id, np.int64)
    put("detection_index", fused.detection_index, np.int64)
    put("observed", fused.observed, bool)
    for i, name in enumerate(_STATE_NAMES):
        put(name, fused.state[:, i], np.float64)
    put("covariance", fused.covariance, np.float64)
    put("laplace_covariance", fused.laplace_covariance, np.float64)
    put("information", fused.information, np.float64)
    put("information_vector", fused.information_vector, np.float64)
    put("success", fused.success, bool)
    put("status", fused.status, np.int8)
    g.create_dataset("message", data=np.array([str(m) for m in fused.message], dtype=object),
                     dtype=h5py.string_dtype(encoding="utf-8"))
    put("iterations", fused.iterations, np.int64)
    put("final_cost", fused.final_cost, np.float64)
    put("degeneracy", fused.degeneracy, np.float64)
    if np.any(fused.rejected):
        put("rejected", fused.rejected, bool)


def write_fused(path: str | os.PathLike, fused: FusedSequence, *,
                output: str | os.PathLike | None = None) -> Path:
    """Store ``fused`` as the ``/fused`` group of the recording at ``path``
    (replacing an existing one), or of a copy of it at ``output``.

    Atomic: the file is copied to a temporary file in the target's folder,
    the group written there, and the copy moved over the target
    (:func:`mmsnap_graph._atomic.atomic_path`). Returns the path written.
    """
    with edited_copy(path, output) as f:
        _fill_group(replace_group(f, FUSED_GROUP, path), _with_clock(fused, f))
    return Path(path) if output is None else Path(output)


def _recording_clock(f: h5py.File) -> tuple[float | None, float | None]:
    """``(frame_period_s, time_origin_s)`` of an open recording file (None
    where it has none): the root attribute and the ``time_origin_s``
    metadata written by time-stamped imports."""
    period = origin = None
    try:
        if "frame_period_s" in f.attrs:
            period = float(f.attrs["frame_period_s"])
        meta = f.get("metadata")
        if isinstance(meta, h5py.Group) and "time_origin_s" in meta.attrs:
            origin = float(meta.attrs["time_origin_s"])
    except H5_ERRORS:
        return None, None
    ok = lambda v: v is not None and np.isfinite(v)  # noqa: E731
    return (period if ok(period) and period > 0 else None), (origin if ok(origin) else None)


def _with_clock(fused: FusedSequence, f: h5py.File) -> FusedSequence:
    """``fused`` with ``time_s`` (and the frame period, the time origin)
    taken from the recording file when it does not carry them."""
    if fused.time_s is not None and fused.time_origin_s is not None:
        return fused
    period, origin = _recording_clock(f)
    changes = {}
    if fused.time_origin_s is None and origin is not None:
        changes["time_origin_s"] = origin
    if fused.time_s is None and period is not None:
        changes["frame_period_s"] = period
    return dataclasses.replace(fused, **changes) if changes else fused


def read_fused(path: str | os.PathLike) -> FusedSequence:
    """Read the ``/fused`` group written by :func:`write_fused`; a missing,
    damaged or inconsistent group, dataset or attribute raises
    :class:`FileFormatError` naming the file and the field."""
    p = Path(path)
    with read_guard(p):
        with open_group(p, FUSED_GROUP,
                        f" has no /{FUSED_GROUP} group; run `mmsnap fuse` first") as group:
            check_format_version(group.attrs, f"{p}:/{FUSED_GROUP}", _FUSED_VERSION)
            fields = _read_fields(group, p)
            period, origin = _recording_clock(group.file)
        # Files of format 1.0 have no time stamps: from the recording's clock.
        if fields["frame_period_s"] is None:
            fields["frame_period_s"] = period
        if fields["time_origin_s"] is None:
            fields["time_origin_s"] = origin
        _check_lengths(fields, p)
        _check_succeeded_rows(fields, p)
        try:
            return FusedSequence(**fields)
        except MmsnapError as exc:
            raise FileFormatError(f"{p}: /{FUSED_GROUP} is inconsistent: {exc}") from exc


def _text(v) -> str:
    return v.decode() if isinstance(v, bytes) else str(v)


def _read_fields(g: h5py.Group, p: Path) -> dict:
    """The keyword arguments of :class:`FusedSequence` from the group ``g``."""

    def ds(name):
        if name not in g:
            raise FileFormatError(f"{p}: /{FUSED_GROUP}/{name} is missing")
        try:
            return g[name][()]
        except H5_ERRORS as exc:
            raise FileFormatError(f"{p}: /{FUSED_GROUP}/{name} cannot be read: {exc}") from exc

    def attr(name, required=True):
        if name not in g.attrs:
            if required:
                raise FileFormatError(f"{p}: attribute /{FUSED_GROUP}.{name} is missing")
            return None
        try:
            return g.attrs[name]
        except H5_ERRORS as exc:
            raise FileFormatError(f"{p}: attribute /{FUSED_GROUP}.{name} cannot be read: "
                                  f"{exc}") from exc

    prior_mean = attr("prior_mean", required=False)
    prior_sigmas = attr("prior_sigmas", required=False)
    columns = {name: ds(name) for name in _STATE_NAMES}
    lengths = {name: c.shape[:1] for name, c in columns.items()}
    if len(set(lengths.values())) != 1:
        raise FileFormatError(f"{p}: /{FUSED_GROUP} datasets disagree in length {lengths}")
    return dict(
        node_names=tuple(_text(n) for n in np.atleast_1d(attr("node_order"))),
        node_poses=np.asarray(attr("node_poses"), dtype=float),
        mode=_text(attr("mode")),
        covariance_method=_text(attr("covariance_method")),
        solver=_text(attr("solver")),
        frame=ds("frame"),
        target=ds("target"),
        label=ds("label"),
        detection_index=ds("detection_index"),
        observed=ds("observed").astype(bool),
        state=np.stack([columns[n] for n in _STATE_NAMES], axis=-1),
        covariance=ds("covariance"),
        laplace_covariance=ds("laplace_covariance"),
        success=ds("success").astype(bool),
        status=ds("status"),
        message=np.array([_text(m) for m in np.atleast_1d(ds("message"))], dtype=object),
        iterations=ds("iterations"),
        final_cost=ds("final_cost"),
        degeneracy=ds("degeneracy"),
        noise_sigmas=np.asarray(attr("noise_sigmas"), dtype=float),
        prior_mean=None if prior_mean is None else np.asarray(prior_mean, dtype=float),
        prior_sigmas=None if prior_sigmas is None else np.asarray(prior_sigmas, dtype=float),
        gate_probability=float(attr("gate_probability")),
        rejected=ds("rejected").astype(bool) if "rejected" in g else None,
        robust=None if attr("robust", required=False) is None else _text(attr("robust")),
        time_s=ds("time_s") if "time_s" in g else None,
        frame_period_s=_optional_float(attr("frame_period_s", required=False)),
        time_origin_s=_optional_float(attr("time_origin_s", required=False)),
        information=ds("information") if "information" in g else None,
        information_vector=ds("information_vector") if "information_vector" in g else None,
        track_id=ds("track_id") if "track_id" in g else None,
    )


def _optional_float(v) -> float | None:
    return None if v is None else float(v)


def _check_lengths(fields: dict, p: Path) -> None:
    """Every per-row dataset has as many rows as ``frame`` (and the right shape)."""
    k = np.shape(fields["frame"])[0] if np.ndim(fields["frame"]) else -1
    n = len(fields["node_names"])
    want = {"frame": (k,), "target": (k,), "label": (k,), "detection_index": (k, n),
            "observed": (k, n), "state": (k, 4), "covariance": (k, 4, 4),
            "laplace_covariance": (k, 4, 4), "success": (k,), "status": (k,), "message": (k,),
            "iterations": (k,), "final_cost": (k,), "degeneracy": (k,), "time_s": (k,),
            "information": (k, 4, 4), "information_vector": (k, 4), "track_id": (k,)}
    for name, shape in want.items():
        if fields[name] is None:  # optional (format 1.0)
            continue
        got = np.shape(fields[name])
        if got != shape:
            raise FileFormatError(f"{p}: /{FUSED_GROUP} datasets disagree in length: {name} "
                                  f"has shape {got}, expected {shape} (frame has {k} rows)")


def _check_succeeded_rows(fields: dict, p: Path) -> None:
    """A row with ``success`` holds a finite state and a finite, symmetric,
    positive-definite covariance (what every solver writes); else
    :class:`FileFormatError` naming the rows (an edited or foreign group:
    ``export`` would print sigma 0, Stone Soup receive a covariance that is
    not positive definite, ``evaluate`` drop the rows quietly)."""
    ok = np.flatnonzero(np.asarray(fields["success"], dtype=bool))
    if not ok.size:
        return
    state = np.asarray(fields["state"], dtype=float)[ok]
    cov = np.asarray(fields["covariance"], dtype=float)[ok]
    finite = np.all(np.isfinite(state), axis=1) & np.all(np.isfinite(cov), axis=(1, 2))
    cov = np.where(finite[:, None, None], cov, np.eye(4))
    scale = np.max(np.abs(cov), axis=(1, 2))
    symmetric = np.all(np.abs(cov - np.swapaxes(cov, 1, 2)) <= 1e-9 * scale[:, None, None],
                       axis=(1, 2))
    smallest = np.linalg.eigvalsh(0.5 * (cov + np.swapaxes(cov, 1, 2)))[:, 0]
    bad = ok[~(finite & symmetric & (smallest > 0))]
    if bad.size:
        frames = np.asarray(fields["frame"])[bad[:5]].tolist()
        raise FileFormatError(
            f"{p}: /{FUSED_GROUP} rows {bad[:5].tolist()}{' ...' if bad.size > 5 else ''} "
            f"(frames {frames}; {bad.size} in all) have success=True but a covariance that is "
            "not finite, symmetric and positive definite (or a state that is not finite); "
            "fuse the recording again (`mmsnap fuse`) or mark the rows failed")
