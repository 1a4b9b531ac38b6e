"""The ``/noise`` group of a recording file: each node's measurement noise as
estimated from the recording's data
(:class:`~mmsnap_graph.data.noise.NoiseEstimate`, made by
:func:`mmsnap_graph.calibration.noise.estimate.estimate_noise`; written by
``mmsnap calibrate`` and ``mmsnap noise``, used by ``mmsnap fuse``).

:func:`write_noise` and :func:`read_noise` are a symmetric pair; the layout is
:data:`NOISE_LAYOUT` (quoted in docs/FORMAT.md). :func:`fill_noise_group`
writes the group into a file already open for writing (to add it in the same
pass as another group).
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping

import h5py
import numpy as np

from ..data.noise import MeasurementNoise, NodeNoiseEstimate, NoiseEstimate
from ..errors import FileFormatError, MmsnapError
from .guard import H5_ERRORS, edited_copy, open_for_reading
from .versions import check_format_version

__all__ = ["NOISE_GROUP", "NOISE_LAYOUT", "write_noise", "read_noise", "fill_noise_group",
           "noise_for_fusion", "noise_lines", "RangeOffsetAtPoses", "read_range_offset"]

#: Name of the HDF5 group written by :func:`write_noise`.
NOISE_GROUP = "noise"
_NOISE_VERSION = "1.0"

#: The ``/noise`` group, for docs/FORMAT.md (the tests check that it is quoted there).
NOISE_LAYOUT = """\
/noise                 attrs: format_version = "1.0", method (str: the estimator),
                              message (str), fallback_sigmas (3,) [range_m, omega_rad,
                              doppler_mps] (used where a component is not identified)
    node_name          (N,) str       every node of the recording, in order
    sigmas             (N, 3) float64 [range_m, omega_rad, doppler_mps] to use: the
                                      estimate where identified, else the fallback's
    identified         (N, 3) bool    True = estimated from the data
    n_residuals        (N, 3) int64   residuals behind each estimate (0 = not identified)
    method             (N,) str       estimator(s) of each node, e.g. "network+temporal"
    reason             (N, 3) str     why a component is not identified ("" if it is)
    tail_factor        (N, 3) float64 the factor each sigma was raised by for heavy tails
                                      (1 = none; optional: 1 when absent)
    range_offset       optional, written by `mmsnap noise --calibration JSON`: the range
                       offset (reflection depth) at the JSON's poses, which `mmsnap fuse
                       --calibration JSON` adds; attrs: offset_m (float, NaN: not
                       identified), message (str)
        poses          (N, 3) float64 the poses it was estimated at, in node_name order
"""

#: The subgroup of ``/noise`` holding a range offset at fixed poses.
_RANGE_OFFSET = "range_offset"

_STR = h5py.string_dtype(encoding="utf-8")


def fill_noise_group(f: h5py.File, estimate: NoiseEstimate) -> None:
    """Write ``estimate`` as ``/noise`` (replacing one) into ``f``, open for writing."""
    if not isinstance(estimate, NoiseEstimate):
        raise FileFormatError(f"estimate must be a NoiseEstimate, got {type(estimate).__name__}")
    if NOISE_GROUP in f:
        del f[NOISE_GROUP]
    g = f.create_group(NOISE_GROUP)
    g.attrs["format_version"] = _NOISE_VERSION
    g.attrs["method"] = estimate.method
    g.attrs["message"] = estimate.message
    g.attrs["fallback_sigmas"] = estimate.fallback.sigmas
    nodes = list(estimate.nodes.values())
    g.create_dataset("node_name", data=np.array(list(estimate.nodes), dtype=object), dtype=_STR)
    g.create_dataset("sigmas", data=np.array([e.noise.sigmas for e in nodes], np.float64))
    g.create_dataset("identified", data=np.array([e.identified for e in nodes], bool))
    g.create_dataset("n_residuals", data=np.array([e.n_residuals for e in nodes], np.int64))
    g.create_dataset("method", data=np.array([e.method for e in nodes], dtype=object), dtype=_STR)
    g.create_dataset("reason", data=np.array([list(e.reasons) for e in nodes], dtype=object),
                     dtype=_STR)
    g.create_dataset("tail_factor", data=np.array([e.tail_factors for e in nodes], np.float64))


@dataclass(frozen=True, kw_only=True, slots=True)
class RangeOffsetAtPoses:
    """The range offset (reflection depth, m; NaN: not identified) the data
    identify at fixed node ``poses`` (name -> (3,)), and what it is in words:
    stored with the noise estimated at those poses, read by ``mmsnap fuse``."""

    offset_m: float
    poses: Mapping[str, np.ndarray]
    message: str = ""


def _fill_range_offset(g: h5py.Group, names: list, offset: RangeOffsetAtPoses) -> None:
    if not isinstance(offset, RangeOffsetAtPoses):
        raise FileFormatError(f"range_offset must be a RangeOffsetAtPoses, got "
                              f"{type(offset).__name__}")
    missing = [n for n in names if n not in offset.poses]
    if missing:
        raise FileFormatError(f"range_offset.poses has no pose for nodes {missing}")
    r = g.create_group(_RANGE_OFFSET)
    r.attrs["offset_m"] = float(offset.offset_m)
    r.attrs["message"] = str(offset.message)
    r.create_dataset("poses", data=np.array([np.asarray(offset.poses[n], np.float64)
                                             for n in names]))


def write_noise(path: str | os.PathLike, estimate: NoiseEstimate, *,
                output: str | os.PathLike | None = None,
                range_offset: RangeOffsetAtPoses | None = None) -> Path:
    """Store ``estimate`` as the ``/noise`` group of the recording at ``path``
    (replacing an existing one), or of a copy of it at ``output``;
    ``range_offset``: the range offset at the poses the noise was estimated
    at (:func:`read_range_offset`).

    Atomic, under the recording lock: the file is copied to a temporary file
    beside the target, the group written there, and the copy moved over the
    target. Returns the path written.
    """
    with edited_copy(path, output) as f:
        try:
            fill_noise_group(f, estimate)
            if range_offset is not None:
                _fill_range_offset(f[NOISE_GROUP], list(estimate.nodes), range_offset)
        except H5_ERRORS as exc:
            if isinstance(exc, MmsnapError):
                raise
            raise FileFormatError(f"{path}: /{NOISE_GROUP} cannot be written (damaged "
                                  f"file?): {exc}") from exc
    return Path(path) if output is None else Path(output)


def _text(v) -> str:
    return v.decode() if isinstance(v, bytes) else str(v)


def _dataset(g: h5py.Group, name: str, where: str, shape: tuple, kind: str) -> np.ndarray:
    if name not in g:
        raise FileFormatError(f"{where}/{name} is missing")
    data = g[name][()]
    if np.shape(data) != shape:
        raise FileFormatError(f"{where}/{name} must have shape {shape}, got {np.shape(data)}")
    if kind == "str":
        return np.array([_text(v) for v in np.ravel(data)], dtype=object).reshape(shape)
    return np.asarray(data)


def _read_group(g: h5py.Group, where: str) -> NoiseEstimate:
    check_format_version(g.attrs, where, _NOISE_VERSION)
    for key in ("method", "message", "fallback_sigmas"):
        if key not in g.attrs:
            raise FileFormatError(f"{where} attribute {key!r} is missing")
    if "node_name" not in g:
        raise FileFormatError(f"{where}/node_name is missing")
    names = g["node_name"][()]
    if np.ndim(names) != 1 or np.size(names) == 0:
        raise FileFormatError(f"{where}/node_name must list at least one node")
    names = np.array([_text(v) for v in names], dtype=object)
    n = names.size
    sig = _dataset(g, "sigmas", where, (n, 3), "num").astype(float)
    ident = _dataset(g, "identified", where, (n, 3), "num").astype(bool)
    counts = _dataset(g, "n_residuals", where, (n, 3), "num").astype(np.int64)
    methods = _dataset(g, "method", where, (n,), "str")
    reasons = _dataset(g, "reason", where, (n, 3), "str")
    tails = (_dataset(g, "tail_factor", where, (n, 3), "num").astype(float)
             if "tail_factor" in g else np.ones((n, 3)))
    fb = np.asarray(g.attrs["fallback_sigmas"], dtype=float)
    if fb.shape != (3,):
        raise FileFormatError(f"{where} attribute fallback_sigmas must have 3 values, got {fb!r}")
    try:
        nodes = {str(names[i]): NodeNoiseEstimate(
            noise=MeasurementNoise(range_m=sig[i, 0], omega_rad=sig[i, 1], doppler_mps=sig[i, 2]),
            identified=tuple(ident[i]), n_residuals=tuple(counts[i]), method=str(methods[i]),
            reasons=tuple(reasons[i]), tail_factors=tuple(tails[i])) for i in range(n)}
        return NoiseEstimate(
            nodes=nodes, fallback=MeasurementNoise(range_m=fb[0], omega_rad=fb[1],
                                                   doppler_mps=fb[2]),
            method=_text(g.attrs["method"]), message=_text(g.attrs["message"]))
    except MmsnapError as exc:
        raise FileFormatError(f"{where} is inconsistent: {exc}") from exc


def read_noise(path: str | os.PathLike) -> NoiseEstimate | None:
    """The :class:`NoiseEstimate` stored by :func:`write_noise`, or None when
    the file has no ``/noise`` group. A missing file, or a damaged or
    inconsistent group, raises :class:`FileFormatError` naming the file and
    the field."""
    p = Path(path)
    with open_for_reading(p) as f:
        if NOISE_GROUP not in f:
            return None
        g = f[NOISE_GROUP]
        if not isinstance(g, h5py.Group):
            raise FileFormatError(f"{p}:/{NOISE_GROUP} is not a group")
        return _read_group(g, f"{p}:/{NOISE_GROUP}")


def read_range_offset(path: str | os.PathLike) -> RangeOffsetAtPoses | None:
    """The range offset ``mmsnap noise --calibration`` stored with the noise,
    or None (no ``/noise`` group, or none stored). A damaged one raises
    :class:`FileFormatError` naming the file and the field."""
    p = Path(path)
    where = f"{p}:/{NOISE_GROUP}/{_RANGE_OFFSET}"
    with open_for_reading(p) as f:
        if NOISE_GROUP not in f or _RANGE_OFFSET not in f[NOISE_GROUP]:
            return None
        g = f[NOISE_GROUP]
        names = [_text(v) for v in np.ravel(g["node_name"][()])] if "node_name" in g else []
        r = g[_RANGE_OFFSET]
        if not isinstance(r, h5py.Group) or "offset_m" not in r.attrs:
            raise FileFormatError(f"{where} attribute 'offset_m' is missing")
        poses = _dataset(r, "poses", where, (len(names), 3), "num").astype(float)
        offset = float(r.attrs["offset_m"])
        if not (np.isnan(offset) or np.isfinite(offset)) or not np.all(np.isfinite(poses)):
            raise FileFormatError(f"{where} holds a value that is not finite")
        message = _text(r.attrs["message"]) if "message" in r.attrs else ""
    return RangeOffsetAtPoses(offset_m=offset, poses=dict(zip(names, poses)), message=message)


def noise_for_fusion(path: str | os.PathLike, node_names, *, per_node: bool = True
                     ) -> tuple[MeasurementNoise | dict[str, MeasurementNoise], str]:
    """The noise ``mmsnap fuse`` uses by default for the recording at
    ``path``, and what it is in words: each node's sigmas of ``/noise``
    (a mapping name -> :class:`MeasurementNoise`, or with ``per_node=False``
    their pooled value, :meth:`NoiseEstimate.pooled`), else the paper's
    :class:`MeasurementNoise`. A ``/noise`` group without some node of
    ``node_names`` raises :class:`FileFormatError`."""
    est = read_noise(path)
    if est is None:
        return (MeasurementNoise(), "no /noise group (run `mmsnap calibrate` or `mmsnap noise`): "
                                    "the paper's sigmas 0.035 m, pi/4 rad, 0.1807 m/s")
    missing = [n for n in node_names if n not in est.nodes]
    if missing:
        raise FileFormatError(f"{path}:/{NOISE_GROUP} has no sigmas for nodes {missing}; "
                              f"rerun `mmsnap noise`")
    text = "\n".join(noise_lines(est))
    if per_node:
        return {n: est.nodes[n].noise for n in node_names}, text
    pooled = est.pooled()
    return pooled, text + "\n  one noise for every node (pooled): " + "  ".join(_sigmas_text(pooled.sigmas))


_UNITS = (("range", "m"), ("omega", "rad"), ("Doppler", "m/s"))
_REASON_CHARS = 90


def _sigmas_text(sigmas, marks=("", "", "")) -> list[str]:
    return [f"{name} {v:.3g} {unit}{mark}" for (name, unit), v, mark in zip(_UNITS, sigmas, marks)]


def _short_reason(reason: str) -> str:
    """The first clause of a stored reason, without its asides, cut to a line
    (the whole reason stays in the file's ``/noise/reason``)."""
    text = re.sub(r"\s*\([^)]*\)", "", reason.split(";")[0]).strip() or "no reason stored"
    if len(text) > _REASON_CHARS:
        text = text[:_REASON_CHARS - 3].rsplit(" ", 1)[0] + "..."
    return text


def _status(e: NodeNoiseEstimate, method: bool, notes: dict[str, str]) -> str:
    """Estimated from how many residuals, or which sigma is not identified
    with a note letter (a), (b), ... per distinct reason, added to ``notes``."""
    how = f" [{e.method}]" if method else ""
    if all(e.identified):
        lo, hi = min(e.n_residuals), max(e.n_residuals)
        return f"estimated from {lo if lo == hi else f'{lo}-{hi}'} residuals{how}"
    names: dict[str, list[str]] = {}
    for (name, _), ident, reason in zip(_UNITS, e.identified, e.reasons):
        if not ident:
            key = notes.setdefault(_short_reason(reason), "abcdefghijklmnopqrstuvwxyz"[len(notes)
                                                                                      % 26])
            names.setdefault(key, []).append(name)
    if len(names) == 1 and not any(e.identified):
        return f"none identified ({next(iter(names))}){how}"
    return ("not identified: " + ", ".join(f"{', '.join(n)} ({k})" for k, n in names.items())
            + how)


def noise_lines(estimate: NoiseEstimate) -> list[str]:
    """``estimate`` as ``mmsnap fuse``, ``monitor`` and ``replay`` print it: a
    header; one short line per node with its three 1-sigmas and their units
    in aligned columns, a ``*`` on each the data do not identify (the
    fallback's value is used there), and the residual count behind the
    estimates or a note letter per sigma not identified; then one line per
    distinct reason, ``(a) ...``."""
    methods = {e.method for e in estimate.nodes.values()}
    shared = f", estimator {methods.pop()}" if len(methods) == 1 else ""
    lines = [f"sigmas from /noise (1-sigma{shared}; * = not identified: the fallback's):"]
    rows = {name: [name] + _sigmas_text(e.noise.sigmas, ["" if ok else "*" for ok in e.identified])
            for name, e in estimate.nodes.items()}
    widths = [max(len(r[i]) for r in rows.values()) for i in range(4)]
    notes: dict[str, str] = {}
    for name, e in estimate.nodes.items():
        cells = "  ".join(c.ljust(w) for c, w in zip(rows[name], widths))
        lines.append(f"  {cells}  {_status(e, not shared, notes)}")
    lines += [f"  ({key}) {reason}" for reason, key in notes.items()]
    return lines
