"""The replay files of TI's Industrial / Applications Visualizer (the mmWave
Radar Toolbox's visualizer, which also runs the 3D people tracking demos)
-> point-table columns.

With "Save data to file" the visualizer writes ``binData/<date>/replay_N.json``:

```
{"cfg": [the .cfg lines], "demo": "...", "device": "...",
 "data": [{"frameData": {"frameNum": 12, "pointCloud": [[x, y, z, doppler, snr, noise,
                                                          track index], ...], ...},
           "timestamp": 1700000000123.4}, ...]}
```

``pointCloud`` rows are in the sensor frame (m, m/s); ``timestamp`` is the
host's ``time.time() * 1000`` (milliseconds) when the frame was read. The SNR
is in dB for the out-of-box demo (the SDK's side info, 0.1 dB steps already
scaled) and a linear power ratio for the people-tracking demos (their
compressed point cloud), named by ``demo``. :func:`replay_columns` returns
the columns under names with their units, for
:func:`~mmsnap_graph.io.ti.point_table.read_point_tables`.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..._validation import parse_json, short_repr
from ...errors import FileFormatError

__all__ = ["replay_columns", "replay_cfg_text", "is_replay", "POINT_FIELDS"]

#: The visualizer's point fields, in the order of a ``pointCloud`` row.
POINT_FIELDS = ("x (m)", "y (m)", "z (m)", "doppler (m/s)", "snr", "noise (db)", "track index")
#: Words of a ``demo`` name whose point cloud carries a linear SNR.
_LINEAR_SNR_DEMOS = ("tracking", "people", "counting")


def is_replay(text: str) -> bool:
    """Whether ``text`` looks like a JSON document (its first character)."""
    return text.lstrip()[:1] in ("{", "[")


def _frames(doc: Any, name: str) -> list:
    if not isinstance(doc, dict) or not isinstance(doc.get("data"), list):
        kind = type(doc).__name__
        keys = f" with keys {sorted(doc)[:8]}" if isinstance(doc, dict) else ""
        raise FileFormatError(f"{name}: a JSON {kind}{keys}, not a replay file of TI's "
                              "visualizer ({'data': [{'frameData': {'pointCloud': [...]}, "
                              "'timestamp': ...}, ...]})")
    return doc["data"]


def _points(frame: Any, i: int, name: str) -> tuple[NDArray, Any, Any]:
    """(points (K, >=4), frame number or None, timestamp or None) of data[i]."""
    where = f"{name}: data[{i}]"
    if not isinstance(frame, dict) or not isinstance(frame.get("frameData", {}), dict):
        raise FileFormatError(f"{where} must be an object with 'frameData' and 'timestamp'")
    data = frame.get("frameData", {})
    cloud = data.get("pointCloud", [])
    try:
        points = np.asarray(cloud if cloud is not None else [], dtype=float)
    except (TypeError, ValueError):
        raise FileFormatError(f"{where}.frameData.pointCloud must be a list of rows of numbers "
                              "[x, y, z, doppler, snr, noise, track index]") from None
    if points.size == 0:
        points = np.zeros((0, len(POINT_FIELDS)))
    if points.ndim != 2 or points.shape[1] < 4:
        raise FileFormatError(f"{where}.frameData.pointCloud must hold rows of at least 4 "
                              f"numbers (x, y, z, doppler), got shape {points.shape}")
    number = data.get("frameNum")
    # parse_json reads an integer beyond the float range as inf; a whole
    # number beyond +-2^62 is no frame number (and no int64 column)
    if number is not None and not (isinstance(number, (int, float)) and math.isfinite(number)
                                   and number == int(number) and abs(number) < 2 ** 62):
        raise FileFormatError(f"{where}.frameData.frameNum must be a whole number within "
                              f"+-2^62, got {short_repr(number)}")
    stamp = frame.get("timestamp")
    if stamp is not None and not (isinstance(stamp, (int, float)) and math.isfinite(stamp)):
        raise FileFormatError(f"{where}.timestamp must be a number (milliseconds), got "
                              f"{short_repr(stamp)}")
    return points, number, stamp


def replay_columns(path: str | Path, text: str | None = None) -> tuple[dict[str, NDArray],
                                                                        str | None]:
    """The columns of a visualizer replay file (module docstring), named
    with their units (``frameNum``, ``timestamp (ms)``, ``x (m)``, ...), and
    the unit of its SNR column (``"db"``, ``"linear"`` for the
    people-tracking demos, None when ``demo`` does not say). Frames without
    ``frameNum`` are numbered in file order."""
    name = str(path)
    if text is None:
        text = Path(path).read_text(encoding="utf-8-sig")
    try:
        doc = parse_json(text)
    except json.JSONDecodeError as exc:
        raise FileFormatError(f"{name}: not a readable JSON file ({exc})") from None
    parts, numbers, stamps = [], [], []
    for i, frame in enumerate(_frames(doc, name)):
        points, number, stamp = _points(frame, i, name)
        parts.append(points)
        numbers.append(np.full(len(points), i if number is None else int(number)))
        stamps.append(np.full(len(points), np.nan if stamp is None else float(stamp)))
    width = max([p.shape[1] for p in parts], default=len(POINT_FIELDS))
    points = np.concatenate([np.pad(p, ((0, 0), (0, width - p.shape[1])),
                                    constant_values=np.nan) for p in parts]) if parts \
        else np.zeros((0, width))
    columns = {"frameNum": np.concatenate(numbers) if numbers else np.zeros(0, int)}
    stamp = np.concatenate(stamps) if stamps else np.zeros(0)
    if stamp.size and np.all(np.isfinite(stamp)):
        columns["timestamp (ms)"] = stamp
    for k, field in enumerate(POINT_FIELDS[:min(width, 6)]):
        columns[field] = points[:, k]
    demo = str(doc.get("demo") or "").lower()
    snr_unit = None
    if demo:
        snr_unit = "linear" if any(w in demo for w in _LINEAR_SNR_DEMOS) else "db"
    return columns, snr_unit


def replay_cfg_text(path: str | Path) -> str | None:
    """The ``.cfg`` lines a replay file holds (its ``cfg``), as one text, or
    None for any other file (or a replay file without them)."""
    p = Path(path)
    try:
        with open(p, encoding="utf-8-sig") as f:
            head = f.read(64)
            if not (p.suffix.lower() == ".json" or is_replay(head)):
                return None
            doc = json.loads(head + f.read())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return None                      # the table reader says what is wrong with it
    lines = doc.get("cfg") if isinstance(doc, dict) else None
    if not isinstance(lines, list) or not all(isinstance(line, str) for line in lines):
        return None
    text = "\n".join(line.rstrip("\n") for line in lines)
    return text if text.strip() else None
