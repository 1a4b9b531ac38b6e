"""Tables of a recording's results for spreadsheets and other tools
(``mmsnap export``): the fused states of ``/fused`` and the node poses of
``/calibration``, as CSV or JSON lines.

Columns carry their units in their names, as in the HDF5 format
(docs/FORMAT.md); angles are radians, with a ``_deg`` twin for people.
``track_id`` is a fused row's person id (the central tracker's,
docs/FORMAT.md "Person ids"; -1 for a row not fused; empty for a file fused
before person ids). A
fused row's covariance is given as its four standard deviations and the
position correlation (``rho_xy``); the full 4 x 4 matrix is in the
``covariance`` column of JSON lines (row-major), which keeps every digit.

A CSV text cell that starts with ``=``, ``+``, ``-``, ``@``, a tab or a
carriage return (a node named ``+SUM(1)`` or ``=cmd|...``) is written with a
leading ``'``, so that a spreadsheet shows it as text instead of running it as
a formula (:func:`csv_cell`); numbers are written as they are (``-1.5``
stays a number). JSON lines keep every string as it is.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
from typing import Any, Iterable

import numpy as np

from ..errors import ValidationError

__all__ = ["TABLES", "FORMATS", "fused_rows", "calibration_rows", "write_table", "csv_cell"]

#: What can be exported, and in which formats.
TABLES = ("fused", "calibration")
FORMATS = ("csv", "jsonl")

FUSED_COLUMNS = ("frame", "time_s", "target", "label", "track_id", "x_m", "y_m", "vx_mps", "vy_mps",
                 "sigma_x_m", "sigma_y_m", "sigma_vx_mps", "sigma_vy_mps", "rho_xy",
                 "success", "status", "message", "nodes")
CALIBRATION_COLUMNS = ("node", "calibrated", "x_m", "y_m", "phi_rad", "phi_deg",
                       "sigma_x_m", "sigma_y_m", "sigma_phi_rad", "lag_frames",
                       "time_offset_s", "time_offset_sigma_s")


def _num(v: float) -> float | None:
    v = float(v)
    return v if math.isfinite(v) else None


def fused_rows(path: str | os.PathLike) -> Iterable[dict[str, Any]]:
    """One dict per row of the recording's ``/fused`` group (columns
    :data:`FUSED_COLUMNS`, plus ``covariance`` as 16 row-major numbers)."""
    from ..io.fused import read_fused

    fused = read_fused(path)
    names = list(fused.node_names)
    time_s = fused.time_s if fused.time_s is not None else np.full(len(fused.frame), np.nan)
    track_id = fused.track_id  # None: a file fused before person ids (an empty column)
    for k in range(len(fused.frame)):
        cov = np.asarray(fused.covariance[k], float)
        sig = np.sqrt(np.clip(np.diagonal(cov), 0, None))
        rho = cov[0, 1] / (sig[0] * sig[1]) if sig[0] > 0 and sig[1] > 0 else float("nan")
        x = fused.state[k]
        yield {"frame": int(fused.frame[k]), "time_s": _num(time_s[k]),
               "target": int(fused.target[k]), "label": int(fused.label[k]),
               "track_id": None if track_id is None else int(track_id[k]),
               "x_m": _num(x[0]), "y_m": _num(x[1]), "vx_mps": _num(x[2]), "vy_mps": _num(x[3]),
               "sigma_x_m": _num(sig[0]), "sigma_y_m": _num(sig[1]),
               "sigma_vx_mps": _num(sig[2]), "sigma_vy_mps": _num(sig[3]), "rho_xy": _num(rho),
               "success": bool(fused.success[k]), "status": int(fused.status[k]),
               "message": str(fused.message[k]),
               "nodes": " ".join(n for n, seen in zip(names, fused.observed[k]) if seen),
               "covariance": [_num(v) for v in cov.ravel()]}


def calibration_rows(path: str | os.PathLike) -> Iterable[dict[str, Any]]:
    """One dict per node of the recording's ``/calibration`` group (columns
    :data:`CALIBRATION_COLUMNS`, plus ``covariance`` as 9 row-major numbers)."""
    from ..io.calibration import read_calibration

    cal = read_calibration(path)
    for name in cal.node_names:
        ok = name in cal.poses
        pose = np.asarray(cal.poses[name], float) if ok else np.full(3, np.nan)
        cov = np.asarray(cal.covariances.get(name, np.full((3, 3), np.nan)), float)
        sig = np.sqrt(np.clip(np.diagonal(cov), 0, None))
        var_t = float(cal.time_offset_variances.get(name, float("nan")))
        yield {"node": name, "calibrated": ok, "x_m": _num(pose[0]), "y_m": _num(pose[1]),
               "phi_rad": _num(pose[2]), "phi_deg": _num(np.degrees(pose[2])),
               "sigma_x_m": _num(sig[0]), "sigma_y_m": _num(sig[1]),
               "sigma_phi_rad": _num(sig[2]), "lag_frames": int(cal.lag_frames.get(name, 0)),
               "time_offset_s": _num(cal.time_offset_s.get(name, 0.0)),
               "time_offset_sigma_s": _num(math.sqrt(var_t)) if var_t >= 0 else None,
               "covariance": [_num(v) for v in cov.ravel()]}


#: First characters that make a spreadsheet read a cell as a formula.
FORMULA_STARTS = ("=", "+", "-", "@", "\t", "\r")


def csv_cell(value: Any) -> Any:
    """A CSV cell: ``""`` for a missing number, a text that a spreadsheet
    would run as a formula (it starts with one of :data:`FORMULA_STARTS`)
    behind a ``'``, anything else as it is."""
    if value is None:
        return ""
    if isinstance(value, str) and value.startswith(FORMULA_STARTS):
        return "'" + value
    return value


def write_table(rows: Iterable[dict[str, Any]], columns: tuple[str, ...], fmt: str) -> str:
    """The rows as text: CSV with ``columns`` (cells by :func:`csv_cell`: an
    empty cell for a missing number, a formula-like text behind a ``'``) or
    JSON lines with every key (``null`` for a missing number)."""
    out = io.StringIO()
    if fmt == "csv":
        writer = csv.DictWriter(out, fieldnames=columns, extrasaction="ignore", lineterminator="\n")
        # The csv module quotes a field holding the line terminator, "\n", but
        # not a bare "\r", which readers take as a line break: such a row is
        # written with every field quoted.
        quoted = csv.DictWriter(out, fieldnames=columns, extrasaction="ignore",
                                lineterminator="\n", quoting=csv.QUOTE_ALL)
        writer.writeheader()
        for row in rows:
            cells = {k: csv_cell(row[k]) for k in columns}
            carriage = any(isinstance(v, str) and "\r" in v for v in cells.values())
            (quoted if carriage else writer).writerow(cells)
    elif fmt == "jsonl":
        for row in rows:
            out.write(json.dumps(row, allow_nan=False) + "\n")
    else:
        raise ValidationError(f"format must be one of {FORMATS}, got {fmt!r}")
    return out.getvalue()
