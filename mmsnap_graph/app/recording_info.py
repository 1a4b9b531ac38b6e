"""What a recording holds, read without loading its arrays (``mmsnap info``).

:func:`recording_info` opens the HDF5 file read-only and returns a plain dict
(JSON-ready): the format, the frame period and time span, each node's pose and
the levels it holds (rows, frames, first and last frame), the metadata, and a
summary of the extension groups that ``mmsnap calibrate``, ``mmsnap noise``
and ``mmsnap fuse`` write (``/calibration``, ``/noise``, ``/fused``).
:func:`format_info` prints it for a person (degrees, units on every value).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from ..io.guard import open_for_reading

__all__ = ["LEVELS", "recording_info", "format_info", "json_ready"]

#: The per-node groups of the format, in pipeline order.
LEVELS = ("cube", "point_cloud", "centroids", "tracks")


def _text(v: Any) -> str:
    return v.decode() if isinstance(v, bytes) else str(v)


def _plain(v: Any) -> Any:
    """A JSON-ready copy of an HDF5 attribute value."""
    if isinstance(v, bytes):
        return v.decode(errors="replace")
    if isinstance(v, np.ndarray):
        return [_plain(x) for x in v.tolist()] if v.dtype.kind in "OSU" else v.tolist()
    if isinstance(v, np.generic):
        return v.item()
    return v


def _level_info(group, name: str) -> dict[str, Any]:
    """Rows and frame span of one level group (cube: frames and shape)."""
    if name == "cube":
        data = group["adc"] if "adc" in group else None
        shape = list(data.shape[:4]) if data is not None else []
        return {"frames": int(shape[0]) if shape else 0, "shape": shape,
                "size_mb": round(float(data.id.get_storage_size()) / 1e6, 1)
                if data is not None else 0.0}
    frames = np.asarray(group["frame"][()]) if "frame" in group else np.zeros(0, np.int64)
    out: dict[str, Any] = {"rows": int(frames.size), "frames": int(np.unique(frames).size)}
    if frames.size:
        out["first_frame"], out["last_frame"] = int(frames.min()), int(frames.max())
    return out


def _node_info(group) -> dict[str, Any]:
    pose = group.attrs.get("pose")
    levels = {name: _level_info(group[name], name) for name in LEVELS if name in group}
    return {"pose": None if pose is None else [float(x) for x in np.ravel(pose)],
            "levels": levels}


def _calibration_info(g) -> dict[str, Any]:
    names = [_text(n) for n in g["node_name"][()]]
    pose = np.asarray(g["pose"][()], float)
    cov = np.asarray(g["covariance"][()], float)
    calibrated = np.asarray(g["calibrated"][()], bool)
    lag = np.asarray(g["lag_frames"][()], np.int64)
    offsets = np.asarray(g["time_offset_s"][()], float) if "time_offset_s" in g \
        else np.zeros(len(names))
    nodes = {}
    for i, name in enumerate(names):
        sig = np.sqrt(np.clip(np.diagonal(cov[i]), 0, None)) if calibrated[i] else None
        nodes[name] = {"calibrated": bool(calibrated[i]),
                       "pose": pose[i].tolist() if calibrated[i] else None,
                       "sigma": None if sig is None else sig.tolist(),
                       "lag_frames": int(lag[i]), "time_offset_s": float(offsets[i])}
    return {"method": _text(g.attrs.get("method", "")), "source": _text(g.attrs.get("source", "")),
            "reference": _text(g.attrs.get("reference", "")),
            "success": bool(g.attrs.get("success", False)),
            "message": _text(g.attrs.get("message", "")), "nodes": nodes}


def _noise_info(g) -> dict[str, Any]:
    names = [_text(n) for n in g["node_name"][()]]
    sigmas = np.asarray(g["sigmas"][()], float)
    ident = np.asarray(g["identified"][()], bool)
    return {"method": _text(g.attrs.get("method", "")),
            "nodes": {name: {"sigmas": sigmas[i].tolist(), "identified": ident[i].tolist()}
                      for i, name in enumerate(names)}}


def _status_text(g) -> dict[int, str]:
    try:
        return {int(k): str(v) for k, v in json.loads(_text(g.attrs["status_messages"])).items()}
    except (KeyError, ValueError, TypeError, AttributeError):
        return {}


def _fused_info(g) -> dict[str, Any]:
    frames = np.asarray(g["frame"][()], np.int64)
    success = np.asarray(g["success"][()], bool)
    status = np.asarray(g["status"][()], np.int64)
    texts = _status_text(g)
    codes, counts = np.unique(status, return_counts=True)
    per_frame = np.bincount(np.unique(frames[success], return_inverse=True)[1]) \
        if success.any() else np.zeros(0, np.int64)
    return {"rows": int(frames.size), "frames": int(np.unique(frames).size),
            "succeeded": int(success.sum()),
            "mode": _text(g.attrs.get("mode", "")), "solver": _text(g.attrs.get("solver", "")),
            "robust": _text(g.attrs.get("robust", "")) or None,
            "status_counts": {f"{int(c)} {texts.get(int(c), '')}".strip(): int(n)
                              for c, n in zip(codes, counts)},
            "max_targets_per_frame": int(per_frame.max()) if per_frame.size else 0}


def recording_info(path: str | os.PathLike) -> dict[str, Any]:
    """What the recording at ``path`` holds (module docstring); raises
    :class:`~mmsnap_graph.errors.FileFormatError` naming the file when it is
    missing or not a readable HDF5 file."""
    path = Path(path)
    with open_for_reading(path) as f:
        _check_recording(f, path)
        period = float(f.attrs["frame_period_s"]) if "frame_period_s" in f.attrs else float("nan")
        order = [_text(n) for n in f.attrs.get("node_order", [])] or list(f.get("nodes", {}))
        nodes = {name: _node_info(f["nodes"][name]) for name in order if name in f.get("nodes", {})}
        spans = [(lv["first_frame"], lv["last_frame"]) for n in nodes.values()
                 for lv in n["levels"].values() if "first_frame" in lv]
        info: dict[str, Any] = {
            "path": str(path), "format": _text(f.attrs.get("format", "")),
            "format_version": _text(f.attrs.get("format_version", "")),
            "frame_period_s": period, "nodes": nodes,
            "metadata": {k: _plain(v) for k, v in f["metadata"].attrs.items()}
            if "metadata" in f else {},
            "truth": "truth" in f,
        }
        if spans:
            first, last = min(s[0] for s in spans), max(s[1] for s in spans)
            info["frames"] = {"first": first, "last": last,
                              "duration_s": (last - first + 1) * period}
        for key, reader in (("calibration", _calibration_info), ("noise", _noise_info),
                            ("fused", _fused_info)):
            info[key] = reader(f[key]) if key in f else None
        info["extensions"] = sorted(k for k in f if k not in ("nodes", "metadata", "truth"))
    return info


def _check_recording(f, path: Path) -> None:
    """An empty or foreign HDF5 file is not a recording: FileFormatError
    (``mmsnap info`` exits 1), as every reader says (the format's check of
    :func:`~mmsnap_graph.io.hdf5.open_recording_file`)."""
    from ..errors import FileFormatError
    from ..io.hdf5 import open_recording_file

    try:
        open_recording_file(path).close()
    except FileFormatError as exc:
        what = "an empty HDF5 file" if not len(f) and not len(f.attrs) else "an HDF5 file"
        raise FileFormatError(f"{path} is {what} but not an mmsnap recording ({exc})") from None


def json_ready(value: Any) -> Any:
    """``value`` (the dict of :func:`recording_info`) with every non-finite
    float as None, so that ``json.dumps(..., allow_nan=False)`` writes JSON
    (``NaN`` is not JSON)."""
    if isinstance(value, dict):
        return {k: json_ready(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_ready(v) for v in value]
    if isinstance(value, float) and not np.isfinite(value):
        return None
    return value


def _pose_text(pose, sigma=None) -> str:
    x, y, phi = pose
    text = f"x {x:+.3f} m, y {y:+.3f} m, phi {np.degrees(phi):+.2f} deg"
    if sigma is not None:
        text += (f" (sigma {sigma[0] * 100:.1f} cm, {sigma[1] * 100:.1f} cm, "
                 f"{np.degrees(sigma[2]):.2f} deg)")
    return text


def _levels_text(levels: dict) -> str:
    parts = []
    for name, lv in levels.items():
        if name == "cube":
            parts.append(f"cube {lv['frames']} frames {'x'.join(map(str, lv['shape'][1:]))} "
                         f"({lv['size_mb']} MB)")
        else:
            span = f", frames {lv['first_frame']}-{lv['last_frame']}" if "first_frame" in lv else ""
            parts.append(f"{name} {lv['rows']} rows in {lv['frames']} frames{span}")
    return "; ".join(parts) or "no data"


def _extension_lines(info: dict) -> list[str]:
    lines = []
    cal = info["calibration"]
    if cal is None:
        lines.append("calibration: none (run `mmsnap calibrate FILE`)")
    else:
        ok = "succeeded" if cal["success"] else "FAILED"
        lines.append(f"calibration: {cal['method']} from {cal['source']}, {ok}; "
                     f"reference {cal['reference']}")
        for name, n in cal["nodes"].items():
            where = _pose_text(n["pose"], n["sigma"]) if n["calibrated"] else "not calibrated"
            lines.append(f"  {name}: {where}; clock offset {n['time_offset_s'] * 1e3:+.1f} ms "
                         f"(lag {n['lag_frames']} frames)")
    noise = info["noise"]
    if noise is None:
        lines.append("noise: none (stored by `mmsnap calibrate` or `mmsnap noise`)")
    else:
        lines.append(f"noise ({noise['method']}): sigmas of range [m], spatial frequency "
                     "[rad], Doppler [m/s]; * = not identified, fallback used")
        for name, n in noise["nodes"].items():
            vals = ", ".join(f"{s:.4g}{'' if ok else '*'}"
                             for s, ok in zip(n["sigmas"], n["identified"]))
            lines.append(f"  {name}: {vals}")
    fused = info["fused"]
    if fused is None:
        lines.append("fused: none (run `mmsnap fuse FILE`)")
    else:
        lines.append(f"fused ({fused['mode']}, {fused['solver']} solver): {fused['rows']} rows in "
                     f"{fused['frames']} frames, {fused['succeeded']} succeeded, at most "
                     f"{fused['max_targets_per_frame']} targets in a frame")
        for status, count in fused["status_counts"].items():
            lines.append(f"  status {status}: {count}")
    return lines


def format_info(info: dict) -> str:
    """:func:`recording_info`'s dict as text for a person (angles in degrees)."""
    lines = [f"{info['path']}: {info['format']} {info['format_version']}, "
             f"frame period {info['frame_period_s'] * 1e3:.2f} ms"]
    if "frames" in info:
        fr = info["frames"]
        lines.append(f"frames {fr['first']}-{fr['last']} ({fr['duration_s']:.2f} s)")
    lines.append(f"{len(info['nodes'])} node(s), the first is the reference:")
    for name, node in info["nodes"].items():
        pose = "pose unknown" if node["pose"] is None else _pose_text(node["pose"])
        lines.append(f"  {name}: {pose}; {_levels_text(node['levels'])}")
    lines.append(f"truth: {'yes' if info['truth'] else 'no'}")
    if info["metadata"]:
        keys = ", ".join(sorted(info["metadata"]))
        lines.append(f"metadata: {keys}")
    lines.extend(_extension_lines(info))
    return "\n".join(lines)
