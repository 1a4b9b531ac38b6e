"""The calibration file formats (docs/FORMAT.md, "/calibration"), in symmetric pairs:

- :func:`write_calibration` / :func:`read_calibration`: the ``/calibration``
  group of a recording file (layout in :data:`CALIBRATION_LAYOUT`) plus each
  calibrated node's ``pose`` attribute, written atomically;
- :func:`write_calibration_json` / :func:`read_calibration_json`: the
  project's calibration JSON, ``{"reference": "S1", "node_names": [...],
  "nodes": {"S1": {"pose": [x_m, y_m, phi_rad], "covariance": [[3x3]],
  "lag_frames": 0, "time_offset_s": 0.0, "time_offset_variance_s2": 0.0}, ...},
  "unreachable": [...], "method": ..., "source": ..., "status": "ok",
  "success": ..., "message": ..., "facts": [{"kind": ..., ...}, ...],
  "edges": [...], "failures": {...}}`` (covariance in the Pose2 body
  tangent; non-finite numbers are ``null``; docs/FORMAT.md says what older
  files without some keys read as).

Both readers return the :class:`~mmsnap_graph.data.calibration.RecordingCalibration`
the writers take, without what is not stored (the noise estimate, which is
the ``/noise`` group: :mod:`.noise`; the joint pose covariance; the edges'
matched points). :func:`load_calibration_poses` reads only ``name -> pose``
from a JSON that may hold nothing but ``{"nodes": {name: {"pose": [...]}}}``;
:func:`load_time_offsets` reads only the clock offsets (node time + offset =
reference time) from either format, for fusion
(:func:`mmsnap_graph.fusion.recording.timing.align_recording`).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from pathlib import Path
from typing import Any, Mapping

import h5py
import numpy as np
from numpy.typing import NDArray

from .._atomic import atomic_path
from .._validation import parse_json, short_repr
from ..data.calibration import PairwiseCalibration, RecordingCalibration
from ..data.calibration_facts import FACT_KINDS, CalibrationFact, CalibrationStatus, LagEvidence
from ..data.recording import Recording
from ..errors import CalibrationError, FileFormatError, MmsnapError, ValidationError
from .guard import H5_ERRORS, open_group
from .hdf5 import update_recording

__all__ = [
    "CALIBRATION_GROUP",
    "CALIBRATION_LAYOUT",
    "write_calibration",
    "read_calibration",
    "write_calibration_json",
    "read_calibration_json",
    "calibration_to_json",
    "calibration_from_json",
    "fact_to_json",
    "fact_from_json",
    "load_calibration_poses",
    "load_time_offsets",
]

CALIBRATION_GROUP = "calibration"
#: Layout of the ``/calibration`` group written by :func:`write_calibration`.
CALIBRATION_LAYOUT = """\
/calibration           attrs: reference (str), method (str), source (str), status (str),
                              success (bool), message (str), json (str: the calibration JSON)
    node_name          (N,) str, every node of the recording in order
    calibrated         (N,) bool, False for nodes with no path to the reference
    pose               (N, 3) float (x_m, y_m, phi_rad), NaN where not calibrated
    covariance         (N, 3, 3) float, Pose2 body tangent, NaN where not calibrated
    lag_frames         (N,) int, node frame k + lag = reference frame k (0 if unknown)
    time_offset_s      (N,) float, clock offset: node time + offset = reference time
                       (0 for the reference and where unknown; optional, 0 when absent)
    time_offset_variance_s2 (N,) float, its variance (NaN where not estimated; optional)
    edges/             one row per pairwise estimate:
        node_a, node_b (E,) str; pose (E, 3); covariance (E, 3, 3);
        rmse_m (E,) float (paper eq. 14); n_frames (E,) int; lag_frames (E,) int
"""


# ---------------------------------------------------------------- JSON
def _jsonable(x) -> Any:
    """Floats and nested lists for JSON; NaN and infinity become None."""
    a = np.asarray(x, dtype=float)
    if a.ndim == 0:
        return float(a) if np.isfinite(a) else None
    return [_jsonable(v) for v in a]


def _floats(x) -> NDArray:
    """The inverse of :func:`_jsonable`: None becomes NaN. A value that is
    no number raises ``TypeError`` or ``ValueError`` (an integer beyond the
    float range, ``10**400``, too: not ``OverflowError``)."""
    if x is None:
        return np.array(np.nan)
    if isinstance(x, (list, tuple)):
        return np.array([_floats(v) for v in x], dtype=float)
    try:
        return np.array(float(x))
    except OverflowError:
        raise ValueError(f"{x!s:.40} is beyond the float range") from None


def calibration_to_json(cal: RecordingCalibration) -> dict[str, Any]:
    """The project's calibration JSON of ``cal`` as a dict (``json.dumps``-able)."""
    nodes = {}
    for n in cal.node_names:
        if n in cal.poses:
            nodes[n] = {"pose": _jsonable(cal.poses[n]),
                        "covariance": _jsonable(cal.covariances[n]),
                        "lag_frames": int(cal.lag_frames.get(n, 0)),
                        "time_offset_s": _jsonable(cal.time_offset_s.get(n, 0.0)),
                        "time_offset_variance_s2": _jsonable(
                            cal.time_offset_variances.get(n, np.nan))}
    return {
        "reference": cal.reference,
        "node_names": list(cal.node_names),
        "nodes": nodes,
        "unreachable": list(cal.unreachable),
        "method": cal.method,
        "source": cal.source,
        "status": cal.status.label,
        "success": bool(cal.success),
        "message": cal.message,
        "facts": [fact_to_json(f) for f in cal.facts],
        "edges": [_edge_json(e) for e in cal.edges],
        "failures": dict(cal.failures),
        **_range_offset_json(cal),
    }


def fact_to_json(fact: CalibrationFact) -> dict[str, Any]:
    """One fact as ``{"kind": ..., <field>: <value>, ...}`` (tuples as lists,
    a status as its label, non-finite numbers as ``null``)."""
    return {"kind": fact.kind, **{f.name: _fact_value(getattr(fact, f.name))
                                  for f in dataclasses.fields(fact)}}


def _fact_value(value) -> Any:
    if isinstance(value, CalibrationStatus):
        return value.label
    if isinstance(value, tuple):
        return [_fact_value(v) for v in value]
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    return value


def fact_from_json(data: Any, where: str) -> CalibrationFact:
    """The fact a :func:`fact_to_json` object holds; CalibrationError naming
    ``where`` and the bad field."""
    if not isinstance(data, Mapping) or data.get("kind") not in FACT_KINDS:
        kind = data.get("kind") if isinstance(data, Mapping) else data
        raise CalibrationError(f"{where}: kind {kind!r} is not one of {sorted(FACT_KINDS)}")
    cls = FACT_KINDS[data["kind"]]
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - names - {"kind"})
    if unknown:
        raise CalibrationError(f"{where}: {data['kind']} has no field(s) {unknown}")
    try:
        return cls(**{k: v for k, v in data.items() if k != "kind"})
    except (TypeError, ValidationError) as exc:
        raise CalibrationError(f"{where}: {exc}") from None


def _edge_json(e: PairwiseCalibration) -> dict[str, Any]:
    out = {"node_a": e.node_a, "node_b": e.node_b, "pose": _jsonable(e.pose),
           "covariance": _jsonable(e.covariance), "rmse_m": _jsonable(e.rmse_m),
           "n_frames": int(e.n_frames), "lag_frames": int(e.lag_frames)}
    if e.lag_ambiguous:
        out["lag_ambiguous"] = True
    if e.lag_evidence is not None:
        out["lag_evidence"] = fact_to_json(e.lag_evidence)
    return out


def _range_offset_json(cal: RecordingCalibration) -> dict[str, Any]:
    """``range_offset_m`` and ``range_offset_variance_m2`` when estimated."""
    if not np.isfinite(cal.range_offset_m):
        return {}
    return {"range_offset_m": float(cal.range_offset_m),
            "range_offset_variance_m2": _jsonable(cal.range_offset_variance)}


def _json_range_offset(data: Mapping, where: str) -> dict[str, float]:
    """The range offset fields of a calibration JSON (NaN when absent)."""
    out = {}
    for key, field_name in (("range_offset_m", "range_offset_m"),
                            ("range_offset_variance_m2", "range_offset_variance")):
        value = data.get(key)
        if value is None:
            out[field_name] = float("nan")
            continue
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise CalibrationError(f"{where}: {key} must be a number, got {value!r}")
        try:
            out[field_name] = float(value)
        except OverflowError:
            out[field_name] = math.copysign(math.inf, value)
        if not math.isfinite(out[field_name]):
            raise CalibrationError(f"{where}: {key} must be finite, got {short_repr(value)}")
    if np.isfinite(out["range_offset_m"]) and abs(out["range_offset_m"]) > 1.0:
        raise CalibrationError(f"{where}: range_offset_m must lie within +-1 m, got "
                               f"{out['range_offset_m']!r}")
    return out


def _outcome(data: Mapping, unreachable, where: str) -> dict[str, Any]:
    """``status`` and ``facts`` of a calibration JSON. Both are optional (a
    file may hold only the poses): without ``status`` it is ``OK`` unless
    ``success`` is false, then ``NODES_UNREACHABLE`` when the file names
    unreachable nodes, else ``SOLVE_FAILED``; without ``facts``, none (a
    ``message`` is the status's own and is not read)."""
    if not isinstance(data.get("success", True), bool):
        raise CalibrationError(f"{where}: success must be true or false, got {data['success']!r}")
    if "status" in data:
        try:
            status = CalibrationStatus.from_name(data["status"])
        except ValidationError as exc:
            raise CalibrationError(f"{where}: {exc}") from None
    elif data.get("success", True):
        status = CalibrationStatus.OK
    else:
        status = (CalibrationStatus.NODES_UNREACHABLE if unreachable
                  else CalibrationStatus.SOLVE_FAILED)
    if "facts" in data:
        facts = data["facts"]
        if not isinstance(facts, list):
            raise CalibrationError(f"{where}: facts must be a list, got {facts!r}")
        facts = tuple(fact_from_json(f, f"{where}: facts[{i}]") for i, f in enumerate(facts))
    else:
        facts = ()
    return {"status": status, "facts": facts}


def _json_float(where: str, name: str, entry: Mapping, key: str, default: float) -> float:
    value = entry.get(key, default) if isinstance(entry, Mapping) else default
    try:
        out = float(_floats(value))
    except (TypeError, ValueError) as exc:
        raise CalibrationError(f"{where}: nodes[{name!r}].{key}={short_repr(value)} is not a "
                               "number") from exc
    if key == "time_offset_s" and not np.isfinite(out):
        raise CalibrationError(f"{where}: nodes[{name!r}].time_offset_s must be finite, "
                               f"got {short_repr(value)}")
    if key != "time_offset_s" and (np.isinf(out) or out < 0):  # a variance; null: not known
        raise CalibrationError(f"{where}: nodes[{name!r}].{key} must be finite and >= 0 "
                               f"(or null), got {short_repr(value)}")
    return out


def _json_timing(data: Any, where: str) -> tuple[dict[str, float], dict[str, float]]:
    nodes = _json_nodes(data, where)
    return ({str(n): _json_float(where, n, e, "time_offset_s", 0.0) for n, e in nodes.items()},
            {str(n): _json_float(where, n, e, "time_offset_variance_s2", None)
             for n, e in nodes.items()})


def _node_pose(where: str, name: str, entry: Any) -> NDArray:
    pose = entry.get("pose") if isinstance(entry, Mapping) else None
    if pose is None:
        raise CalibrationError(f"{where}: nodes[{name!r}] has no 'pose'")
    try:
        arr = _floats(pose)
    except (TypeError, ValueError) as exc:
        raise CalibrationError(f"{where}: nodes[{name!r}].pose={short_repr(pose)} is not numeric "
                               f"({exc})") from exc
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise CalibrationError(f"{where}: nodes[{name!r}].pose must be 3 finite numbers "
                               f"[x_m, y_m, phi_rad], got {pose!r}")
    if abs(arr[2]) > 2 * np.pi + 1e-9:
        phi = float(arr[2])
        raise CalibrationError(f"{where}: nodes[{name!r}].pose phi_rad={phi!r} lies outside "
                               f"[-2 pi, 2 pi]: the heading is in radians (degrees? {phi:g} deg "
                               f"is {np.deg2rad(phi):.6g} rad)")
    return arr


def _json_int(where: str, field: str, value: Any) -> int:
    """An integer field (``lag_frames``, ``n_frames``): a JSON integer, or a
    float that is one, within +-2^31."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise CalibrationError(f"{where}: {field}={value!r} must be an integer")
    whole = isinstance(value, int) or (math.isfinite(value) and value == int(value))
    if not (whole and abs(value) <= 2 ** 31):
        raise CalibrationError(f"{where}: {field}={value!r} must be an integer within +-2^31")
    return int(value)


def _json_names(where: str, field: str, value: Any) -> tuple[str, ...]:
    """A list of node names."""
    if not isinstance(value, (list, tuple)) or not all(isinstance(v, str) for v in value):
        raise CalibrationError(f"{where}: {field} must be a list of node names, got {value!r}")
    return tuple(value)


def _json_nodes(data: Any, where: str) -> Mapping:
    nodes = data.get("nodes") if isinstance(data, Mapping) else None
    if not isinstance(nodes, Mapping) or not nodes:
        raise CalibrationError(f"{where}: missing or empty 'nodes' mapping")
    return nodes


def _json_covariance(where: str, name: str, entry: Mapping) -> NDArray:
    cov = entry.get("covariance")
    if cov is None:
        return np.full((3, 3), np.nan)
    try:
        arr = _floats(cov)
    except (TypeError, ValueError) as exc:
        raise CalibrationError(f"{where}: nodes[{name!r}].covariance is not numeric") from exc
    if arr.shape != (3, 3):
        raise CalibrationError(f"{where}: nodes[{name!r}].covariance must be 3 x 3, "
                               f"got shape {arr.shape}")
    if np.any(np.isinf(arr)):  # null (NaN) entries mean "not known"; infinity is no variance
        raise CalibrationError(f"{where}: nodes[{name!r}].covariance must be finite (or null), "
                               f"got {short_repr(cov)}")
    return arr


def _json_edge(where: str, i: int, e: Any) -> PairwiseCalibration:
    try:
        at = f"edges[{i}]"
        evidence = e.get("lag_evidence")
        if evidence is not None:
            evidence = fact_from_json(evidence, f"{where}: {at}.lag_evidence")
            if not isinstance(evidence, LagEvidence):
                raise CalibrationError(f"{where}: {at}.lag_evidence must be a lag_evidence "
                                       f"fact, got {evidence.kind}")
        return PairwiseCalibration(
            node_a=str(e["node_a"]), node_b=str(e["node_b"]), pose=_floats(e["pose"]),
            covariance=_floats(e["covariance"]), rmse_m=float(_floats(e.get("rmse_m"))),
            n_frames=_json_int(where, f"{at}.n_frames", e.get("n_frames", 0)),
            lag_frames=_json_int(where, f"{at}.lag_frames", e.get("lag_frames", 0)),
            lag_evidence=evidence, lag_ambiguous=bool(e.get("lag_ambiguous", False)))
    except (KeyError, TypeError, ValueError, AttributeError, OverflowError) as exc:
        if isinstance(exc, CalibrationError):
            raise
        raise CalibrationError(f"{where}: edges[{i}] is not a pose edge ({exc})") from exc


def calibration_from_json(data: Mapping, *, where: str = "calibration") -> RecordingCalibration:
    """A :class:`RecordingCalibration` from parsed calibration JSON.

    Only ``nodes`` with each node's ``pose`` is required; a missing
    ``covariance`` is NaN, ``lag_frames`` and ``time_offset_s`` 0,
    ``time_offset_variance_s2`` NaN, ``reference`` the first node,
    ``node_names`` the calibrated then the unreachable nodes, the status
    ``OK`` (a file without ``status`` and ``facts``: :func:`_outcome`).
    Raises :class:`CalibrationError` naming the bad field.
    """
    nodes = _json_nodes(data, where)
    poses = {str(n): _node_pose(where, n, e) for n, e in nodes.items()}
    covs = {str(n): _json_covariance(where, n, e) for n, e in nodes.items()}
    lags = {str(n): _json_int(where, f"nodes[{n!r}].lag_frames", e.get("lag_frames", 0) or 0)
            for n, e in nodes.items()}
    unreachable = _json_names(where, "unreachable", data.get("unreachable", []))
    names = _json_names(where, "node_names", data.get("node_names", [*poses, *unreachable]))
    missing = [n for n in poses if n not in names]
    if missing:
        raise CalibrationError(f"{where}: nodes {missing} are not in node_names {list(names)}")
    edges, failures = data.get("edges", []), data.get("failures", {})
    if not isinstance(edges, list):
        raise CalibrationError(f"{where}: edges must be a list, got {edges!r}")
    if not isinstance(failures, Mapping):
        raise CalibrationError(f"{where}: failures must be an object, got {failures!r}")
    for key in ("reference", "method", "source", "message"):
        if not isinstance(data.get(key, ""), str):
            raise CalibrationError(f"{where}: {key} must be a string, got {data[key]!r}")
    try:
        offsets, variances = _json_timing(data, where)
        return RecordingCalibration(
            reference=str(data.get("reference", next(iter(poses)))), node_names=names,
            poses=poses, covariances=covs, lag_frames=lags, unreachable=unreachable,
            edges=tuple(_json_edge(where, i, e) for i, e in enumerate(edges)),
            method=str(data.get("method", "")), source=str(data.get("source", "")),
            failures={str(k): str(v) for k, v in failures.items()},
            time_offset_s=offsets, time_offset_variances=variances,
            **_outcome(data, unreachable, where), **_json_range_offset(data, where))
    except MmsnapError as exc:
        if isinstance(exc, CalibrationError):
            raise
        raise CalibrationError(f"{where}: {exc}") from None


def _parse_json(source: str | os.PathLike | Mapping) -> tuple[Any, str]:
    if isinstance(source, Mapping):
        return source, "calibration"
    path = Path(source)
    try:
        return parse_json(path.read_text()), str(path)
    except FileNotFoundError as exc:
        raise CalibrationError(f"calibration file {path} does not exist") from exc
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise CalibrationError(f"{path} is not readable calibration JSON: {exc}") from exc
    except RecursionError:
        raise CalibrationError(f"{path} is not calibration JSON: nested too deeply") from None


def write_calibration_json(path: str | os.PathLike, cal: RecordingCalibration) -> Path:
    """Write the calibration JSON of ``cal`` (:func:`calibration_to_json`) to
    ``path``, atomically."""
    dst = Path(path)
    with atomic_path(dst) as tmp:
        tmp.write_text(json.dumps(calibration_to_json(cal), indent=2) + "\n")
    return dst


def read_calibration_json(source: str | os.PathLike | Mapping) -> RecordingCalibration:
    """The :class:`RecordingCalibration` in calibration JSON (a path, or the
    parsed mapping); :func:`calibration_from_json` says what may be missing."""
    data, where = _parse_json(source)
    return calibration_from_json(data, where=where)


def load_calibration_poses(source: str | os.PathLike | Mapping) -> dict[str, NDArray]:
    """Node poses ``name -> (3,) (x_m, y_m, phi_rad)`` from calibration JSON
    (a path or the parsed mapping); only the nodes' ``pose`` entries are read."""
    data, where = _parse_json(source)
    return {str(n): _node_pose(where, n, e) for n, e in _json_nodes(data, where).items()}


# ---------------------------------------------------------------- HDF5
def _strings(group: h5py.Group, name: str, values) -> None:
    group.create_dataset(name, data=np.array(list(values), dtype=object),
                         dtype=h5py.string_dtype())


def _write_nodes(g: h5py.Group, cal: RecordingCalibration) -> None:
    names = list(cal.node_names)
    n = len(names)
    pose = np.full((n, 3), np.nan)
    cov = np.full((n, 3, 3), np.nan)
    lag = np.zeros(n, np.int64)
    ok = np.zeros(n, bool)
    tau = np.array([cal.time_offset_s.get(name, 0.0) for name in names], dtype=float)
    tau_var = np.array([cal.time_offset_variances.get(name, np.nan) for name in names],
                       dtype=float)
    for i, name in enumerate(names):
        if name in cal.poses:
            pose[i], cov[i], ok[i] = cal.poses[name], cal.covariances[name], True
            lag[i] = cal.lag_frames.get(name, 0)
    _strings(g, "node_name", names)
    g.create_dataset("calibrated", data=ok)
    g.create_dataset("pose", data=pose)
    g.create_dataset("covariance", data=cov)
    g.create_dataset("lag_frames", data=lag)
    g.create_dataset("time_offset_s", data=tau)
    g.create_dataset("time_offset_variance_s2", data=tau_var)


def _write_edges(g: h5py.Group, edges) -> None:
    e = g.create_group("edges")
    _strings(e, "node_a", [x.node_a for x in edges])
    _strings(e, "node_b", [x.node_b for x in edges])
    e.create_dataset("pose", data=np.array([x.pose for x in edges]).reshape(-1, 3))
    e.create_dataset("covariance", data=np.array([x.covariance for x in edges]).reshape(-1, 3, 3))
    e.create_dataset("rmse_m", data=np.array([x.rmse_m for x in edges], dtype=float))
    e.create_dataset("n_frames", data=np.array([x.n_frames for x in edges], np.int64))
    e.create_dataset("lag_frames", data=np.array([x.lag_frames for x in edges], np.int64))


def _write_group(f: h5py.File, cal: RecordingCalibration) -> None:
    if CALIBRATION_GROUP in f:
        del f[CALIBRATION_GROUP]
    g = f.create_group(CALIBRATION_GROUP)
    g.attrs["reference"] = cal.reference
    g.attrs["method"] = cal.method
    g.attrs["source"] = cal.source
    g.attrs["status"] = cal.status.label
    g.attrs["success"] = bool(cal.success)
    g.attrs["message"] = cal.message
    g.attrs["json"] = json.dumps(calibration_to_json(cal))
    _write_nodes(g, cal)
    _write_edges(g, cal.edges)


def write_calibration(path: str | os.PathLike, recording: Recording, cal: RecordingCalibration,
                      *, output: str | os.PathLike | None = None) -> Path:
    """Store ``cal`` in the recording file at ``path`` (or a copy at
    ``output``): calibrated nodes' ``pose`` attributes and the
    ``/calibration`` group (:data:`CALIBRATION_LAYOUT`), atomically.

    ``recording`` is the file's content (e.g. ``read_recording(path,
    load_cubes=False)``); cubes not loaded are kept. Read it back with
    :func:`read_calibration`.
    """
    src = Path(path)
    if not src.exists():
        raise FileFormatError(f"{src} does not exist")
    dst = src if output is None else Path(output)
    rec = recording
    for n, pose in cal.poses.items():
        rec = rec.with_node(dataclasses.replace(rec.nodes[n], pose=np.asarray(pose, dtype=float)))

    # One pass: the new file is written beside dst from rec and src's extension
    # groups, then the group is added; one temporary copy on disk, not two.
    return update_recording(src, rec, keep_cubes=True, output=dst,
                            edit=lambda f: _write_group(f, cal))


def _member(g: h5py.Group, key: str, where: str) -> NDArray:
    if key not in g:
        raise FileFormatError(f"{where}/{key} is missing")
    data = g[key][()]
    if data.dtype.kind in "OS":
        return np.array([v.decode() if isinstance(v, bytes) else str(v) for v in data], dtype=object)
    return np.asarray(data)


def _read_edges(g: h5py.Group, where: str, stored: list) -> tuple[PairwiseCalibration, ...]:
    """The edges datasets; ``stored`` the JSON attribute's edges (their
    lag evidence and ambiguity, which the datasets do not hold)."""
    if "edges" not in g:
        raise FileFormatError(f"{where}/edges is missing")
    e, w = g["edges"], f"{where}/edges"
    cols = {k: _member(e, k, w) for k in ("node_a", "node_b", "pose", "covariance", "rmse_m",
                                          "n_frames", "lag_frames")}
    extra = [{}] * cols["node_a"].size
    if len(stored) == cols["node_a"].size:
        extra = [{"lag_evidence": x.lag_evidence, "lag_ambiguous": x.lag_ambiguous}
                 for x in stored]
    return tuple(PairwiseCalibration(
        node_a=str(cols["node_a"][i]), node_b=str(cols["node_b"][i]), pose=cols["pose"][i],
        covariance=cols["covariance"][i], rmse_m=float(cols["rmse_m"][i]),
        n_frames=int(cols["n_frames"][i]), lag_frames=int(cols["lag_frames"][i]), **extra[i])
        for i in range(cols["node_a"].size))


def _read_group(g: h5py.Group, where: str) -> RecordingCalibration:
    cols = {k: _member(g, k, where) for k in ("node_name", "calibrated", "pose", "covariance",
                                              "lag_frames")}
    names = tuple(str(n) for n in cols["node_name"])
    ok = cols["calibrated"].astype(bool)
    if ok.shape != (len(names),):
        raise FileFormatError(f"{where}/calibrated must have shape ({len(names)},), "
                              f"got {ok.shape}")
    attrs = {}
    for key in ("reference", "method", "source", "success", "message"):
        if key not in g.attrs:
            raise FileFormatError(f"{where} attribute {key!r} is missing")
        attrs[key] = g.attrs[key]
    extra = parse_json(g.attrs["json"]) if "json" in g.attrs else {}
    if not isinstance(extra, Mapping):
        raise FileFormatError(f"{where} attribute 'json' must hold a JSON object")
    stored = calibration_from_json(extra, where=where).edges if "nodes" in extra else []
    unreachable = tuple(n for i, n in enumerate(names) if not ok[i])
    outcome = {"success": bool(attrs["success"]), "message": str(attrs["message"]),
               **({"status": str(g.attrs["status"])} if "status" in g.attrs else {}),
               **{k: extra[k] for k in ("status", "facts") if k in extra}}
    offsets, variances = _group_timing(g, names, where)
    return RecordingCalibration(
        reference=str(attrs["reference"]), node_names=names,
        poses={n: cols["pose"][i].astype(float) for i, n in enumerate(names) if ok[i]},
        covariances={n: cols["covariance"][i].astype(float) for i, n in enumerate(names) if ok[i]},
        lag_frames={n: int(cols["lag_frames"][i]) for i, n in enumerate(names) if ok[i]},
        unreachable=unreachable, edges=_read_edges(g, where, list(stored)),
        method=str(attrs["method"]), source=str(attrs["source"]),
        failures={str(k): str(v) for k, v in dict(extra.get("failures", {})).items()},
        time_offset_s=offsets, time_offset_variances=variances,
        **_outcome(outcome, unreachable, where), **_json_range_offset(extra, where))


def _group_timing(g: h5py.Group, names, where: str):
    """name -> clock offset and variance of the group (0 and NaN when the
    file predates them)."""
    n = len(names)
    tau = (_member(g, "time_offset_s", where).astype(float) if "time_offset_s" in g
           else np.zeros(n))
    var = (_member(g, "time_offset_variance_s2", where).astype(float)
           if "time_offset_variance_s2" in g else np.full(n, np.nan))
    if tau.shape != (n,) or var.shape != (n,):
        raise FileFormatError(f"{where}/time_offset_s and time_offset_variance_s2 must have "
                              f"shape ({n},), got {tau.shape} and {var.shape}")
    return ({str(m): float(tau[i]) for i, m in enumerate(names)},
            {str(m): float(var[i]) for i, m in enumerate(names)})


def read_calibration(path: str | os.PathLike) -> RecordingCalibration:
    """The :class:`RecordingCalibration` stored by :func:`write_calibration` in
    the ``/calibration`` group of the file at ``path`` (without the step
    results ``pose_graph`` and ``joint``). Raises :class:`FileFormatError`
    naming the missing group, dataset or attribute."""
    path = Path(path)
    with open_group(path, CALIBRATION_GROUP,
                    f": /{CALIBRATION_GROUP} is missing (run mmsnap calibrate)") as group:
        try:
            return _read_group(group, f"{path}:/{CALIBRATION_GROUP}")
        except (*H5_ERRORS, json.JSONDecodeError) as exc:
            if isinstance(exc, MmsnapError):
                raise
            raise FileFormatError(f"{path}:/{CALIBRATION_GROUP} is malformed: {exc}") from exc


def load_time_offsets(source: str | os.PathLike | Mapping
                      ) -> tuple[dict[str, float], dict[str, float]]:
    """Clock offsets ``name -> seconds`` (node time + offset = reference
    time) and their variances (s^2) from calibration JSON (a path or the
    parsed mapping) or from the ``/calibration`` group of an HDF5 recording
    (a path ending in ``.h5``/``.hdf5``); 0 and NaN where a file holds
    none."""
    if not isinstance(source, Mapping) and Path(source).suffix.lower() in (".h5", ".hdf5"):
        path = Path(source)
        with open_group(path, CALIBRATION_GROUP,
                        f": /{CALIBRATION_GROUP} is missing (run mmsnap calibrate)") as group:
            where = f"{path}:/{CALIBRATION_GROUP}"
            try:
                names = tuple(str(n) for n in _member(group, "node_name", where))
                return _group_timing(group, names, where)
            except H5_ERRORS as exc:
                if isinstance(exc, MmsnapError):
                    raise
                raise FileFormatError(f"{where} is malformed: {exc}") from exc
    data, where = _parse_json(source)
    return _json_timing(data, where)
