"""Tabular point-cloud logs (CSV, ``.npy``, pandas DataFrame) -> :class:`PointCloud3D`.

One row per point. Column names are matched case-insensitively, with the
aliases below (a ``columns=`` mapping renames others):

- the frame: ``frame`` (aliases ``frame_number``, ``framenum``, ``numframe``)
  and/or a time stamp ``time_s`` (``time``, ``timestamp``); one of them is
  required; without ``frame``, frames are numbered from the time stamps;
- Cartesian points: ``x_m, y_m, z_m, doppler_mps`` (``x, y, z, doppler``,
  ``velocity``, ``v``), or spherical points: ``range_m, azimuth_rad,
  elevation_rad, doppler_mps`` (``range``, ``azimuth``/``az``,
  ``elevation``/``el``; TI's convention, see ``factors.projection``);
- optional: ``snr_db`` (``snr``), ``noise_db`` (``noise``), and ``node``
  (``sensor``, ``radar``) when one table holds several radars.

A unit written in a header is read (``X (m)``, ``Azimuth [deg]``,
``Timestamp (ms)``, ``SNR (0.1 dB)``; :mod:`.headers`), as are the header
sets of TI's tools (``columns="visualizer"``, ``"sdk-script"``). A CSV file's
cells may be separated by commas, semicolons (with decimal commas) or tabs;
a replay file of TI's visualizer (JSON, :mod:`.replay`) is read as a table.
"""

from __future__ import annotations

import csv
import os
import warnings
import zipfile
from pathlib import Path
from typing import Any, Literal, Mapping

import numpy as np
from numpy.typing import NDArray

from factors.projection import spherical_to_cartesian
from ..._validation import outlying_frames
from ...errors import FileFormatError, MmsnapWarning, ValidationError
from .csv_columns import plain_csv_columns
from .headers import (PRESETS, QUANTITY, detect_preset, header_unit, preset_names,
                      suggest_preset, unit_factor)
from .inputs import require_file
from .replay import is_replay, replay_columns
from .point_cloud import MAX_COORDINATE_M, MAX_SPEED_MPS, PointCloud3D

__all__ = ["CARTESIAN_COLUMNS", "SPHERICAL_COLUMNS", "SNR_UNITS", "read_point_table",
           "read_point_tables", "csv_text_columns"]

CARTESIAN_COLUMNS = ("x_m", "y_m", "z_m", "doppler_mps")
SPHERICAL_COLUMNS = ("range_m", "azimuth_rad", "elevation_rad", "doppler_mps")

_ALIASES = {
    "frame": ("frame", "frame_number", "framenum", "numframe", "frame_id", "frame number",
              "frame #", "frame#", "frame no", "frame_no"),
    "time_s": ("time_s", "time", "timestamp", "t"),
    "x_m": ("x_m", "x"), "y_m": ("y_m", "y"), "z_m": ("z_m", "z"),
    "doppler_mps": ("doppler_mps", "doppler", "velocity", "v", "radial_velocity",
                    "radial velocity"),
    "range_m": ("range_m", "range", "r"),
    "azimuth_rad": ("azimuth_rad", "azimuth", "az"),
    "elevation_rad": ("elevation_rad", "elevation", "el"),
    "snr_db": ("snr_db", "snr"), "noise_db": ("noise_db", "noise"),
    "node": ("node", "sensor", "radar"),
}
_TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
#: Per column, the largest magnitude a radar point can have (a corrupted cell).
_LIMITS = {"x_m": MAX_COORDINATE_M, "y_m": MAX_COORDINATE_M, "z_m": MAX_COORDINATE_M,
           "range_m": MAX_COORDINATE_M, "doppler_mps": MAX_SPEED_MPS}
#: Time stamps beyond this (about 31,700 years) are not a clock (a bad cell).
_MAX_TIME_S = 1e12
#: The SNR column's units: dB, TI's side-info steps of 0.1 dB (the mmWave
#: SDK's TLV 7 and its example parser's CSV), or a linear power ratio (the
#: people-tracking demos' point cloud).
SNR_UNITS = ("db", "0.1db", "linear")
#: No TI radar reports SNRs this high in dB (the real recordings in
#: data/real/darksz: median 15-20 dB, at most 51 dB): a median or largest
#: value beyond these is an SNR in another unit.
MAX_MEDIAN_SNR_DB = 60.0
MAX_SNR_DB = 120.0


def _read_text(path: Path) -> dict[str, NDArray]:
    """A CSV file (:func:`csv_text_columns`) or a replay file of TI's
    visualizer (JSON, :func:`~.replay.replay_columns`) -> name -> column."""
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (UnicodeDecodeError, OSError) as exc:
        raise FileFormatError(f"{path}: not a readable CSV table ({exc}); a binary log of a "
                              "demo's data UART is read by mmsnap import ti-uart") from None
    if path.suffix.lower() == ".json" or is_replay(text):
        columns, snr_unit = replay_columns(path, text)
        if snr_unit is not None and "snr" in columns:
            columns[f"snr ({snr_unit})"] = columns.pop("snr")
        return columns
    return csv_text_columns(text, path)


#: Cell separators a table may use (a spreadsheet of a locale with decimal
#: commas writes semicolons).
DELIMITERS = (",", ";", "\t")


def _delimiter(lines: list[str]) -> str:
    """The separator of the header line: the one of :data:`DELIMITERS` it
    holds most of (a comma when it holds none)."""
    header = lines[0] if lines else ""
    counts = [header.count(d) for d in DELIMITERS]
    return DELIMITERS[int(np.argmax(counts))] if max(counts) else ","


def csv_text_columns(text: str, name: str | os.PathLike = "CSV table", *,
                     fast: bool = True) -> dict[str, NDArray]:
    """The text of a CSV point table -> name -> column, without pandas, as
    :func:`read_point_tables` reads a CSV file (``name`` names it in errors).

    Cells are separated by commas, semicolons or tabs (the one the header
    line holds most of; with semicolons, a decimal comma is read as a
    point). Blank lines and lines starting with ``#`` are skipped, spaces
    around a cell are dropped; a column whose every non-empty cell is a
    number is a float column (an empty cell is NaN), any other a column of
    strings (the errors that follow then name the line of a bad cell). A
    plain comma table is parsed by :func:`~.csv_columns.plain_csv_columns`
    with the same result (``fast=False``: never, for comparison)."""
    plain = plain_csv_columns(text) if fast else None    # the common case, parsed by NumPy
    if plain is not None:
        _no_duplicates(list(plain), str(name))
        return plain
    kept = [(k, line) for k, line in enumerate(text.splitlines(), start=1)
            if line.strip() and not line.lstrip().startswith("#")]
    lines = [line for _, line in kept]
    sep = _delimiter(lines)
    try:
        # Without quotes a line is its cells split at the separators (several
        # times faster than the csv module on large logs).
        rows = (list(csv.reader(lines, delimiter=sep, skipinitialspace=True)) if '"' in text
                else [line.split(sep) for line in lines])
    except csv.Error as exc:
        raise FileFormatError(f"{name}: not a readable CSV table ({exc})") from None
    if not rows:
        raise FileFormatError(f"{name}: not a readable CSV table (no header line)")
    header = [c.strip() for c in rows[0]]
    _no_duplicates(header, str(name))
    if set(map(len, rows)) != {len(header)}:
        k = next(k for k, row in enumerate(rows) if len(row) != len(header))
        raise FileFormatError(f"{name}: line {kept[k][0]} has {len(rows[k])} cells, the header "
                              f"(line {kept[0][0]}) names {len(header)} columns"
                              + (f" (cells separated by {sep!r})" if sep != "," else ""))
    cells = list(zip(*rows[1:])) or [()] * len(header)
    return {column: _csv_column(values, decimal_comma=sep == ";")
            for column, values in zip(header, cells)}


def _csv_column(cells: tuple, *, decimal_comma: bool = False) -> NDArray:
    """Floats when every non-empty cell is a number (empty: NaN; with
    ``decimal_comma``, ``1,5`` is 1.5), else the cells as strings without
    surrounding spaces."""
    try:
        return np.array(cells, dtype=float)        # NumPy parses the text (fast)
    except ValueError:
        pass
    number = (lambda c: float(c.replace(",", "."))) if decimal_comma else float
    try:
        return np.array([number(c) if c.strip() else np.nan for c in cells], dtype=float)
    except ValueError:
        return np.char.strip(np.array(cells, dtype=str))


def _as_columns(source: Any, name: str) -> dict[str, NDArray]:
    """A DataFrame, a structured array, a .npy or .npz path or a CSV path ->
    name -> column."""
    if isinstance(source, (str, os.PathLike)):
        path = Path(source)
        require_file(path, "point table")
        if path.suffix.lower() not in (".npy", ".npz"):
            return _read_text(path)
        try:
            arr = np.load(path, allow_pickle=False)
            if isinstance(arr, np.lib.npyio.NpzFile):
                with arr:
                    return {k: arr[k] for k in arr.files}
        except (ValueError, OSError, EOFError, zipfile.BadZipFile) as exc:
            raise FileFormatError(f"{path}: not a plain NumPy array file ({exc})") from None
        return _as_columns(arr, name)
    if hasattr(source, "columns") and hasattr(source, "to_numpy"):
        names = [str(c) for c in source.columns]
        _no_duplicates(names, name)
        return {n: source[c].to_numpy() for n, c in zip(names, source.columns)}
    if isinstance(source, np.ndarray) and source.dtype.names:
        return {k: source[k] for k in source.dtype.names}
    if isinstance(source, Mapping):
        return {str(k): np.asarray(v) for k, v in source.items()}
    raise FileFormatError(f"{name}: a point table must be a CSV or .npy/.npz file, a "
                          "DataFrame, a structured array or a mapping of columns; got "
                          f"{type(source).__name__}" + (" (a plain array has no column "
                                                        "names)" if isinstance(source,
                                                                               np.ndarray)
                                                        else ""))


def _no_duplicates(names: list[str], name: str) -> None:
    """Column names must be unique (ignoring case and spaces around them)."""
    seen: dict[str, str] = {}
    for n in names:
        key = n.strip().lower()
        if key in seen:
            raise FileFormatError(f"{name}: columns {seen[key]!r} and {n!r} have the same name; "
                                  "rename one")
        seen[key] = n


def _checked_columns(raw: dict[str, Any], name: str) -> dict[str, NDArray]:
    """Every column one-dimensional, of numbers or strings, all of one length."""
    _no_duplicates(list(raw), name)
    out, lengths = {}, {}
    for key, value in raw.items():
        arr = np.asarray(value)
        if arr.ndim != 1:
            raise FileFormatError(f"{name}: column {key} must be one-dimensional (one value "
                                  f"per point), got shape {arr.shape}")
        if arr.dtype.kind not in "biufUSO":
            raise FileFormatError(f"{name}: column {key} has dtype {arr.dtype}; a point table "
                                  "holds numbers (and node names)")
        out[key], lengths[key] = arr, arr.shape[0]
    if len(set(lengths.values())) > 1:
        raise FileFormatError(f"{name}: columns differ in length {lengths}; every column "
                              "needs one value per point")
    return out


def _target(key: str, base: str, renames: dict, preset) -> tuple[str | None, str | None]:
    """(canonical column, the preset's unit) of a header: the ``columns``
    rename, else the preset's column, else the alias of the whole name or of
    the name without its unit ((None, None): not a column this reader knows)."""
    if key in renames:
        return renames[key], None
    if preset is not None and base in preset.columns:
        return preset.columns[base]
    for canon, aliases in _ALIASES.items():
        if key in aliases or base in aliases:
            return canon, None
    return None, None


def _canonical(raw: dict[str, NDArray], columns: Mapping[str, str] | str | None,
               name: str) -> tuple[dict[str, NDArray], dict[str, str]]:
    """The columns under their canonical names (``_ALIASES``) and the unit of
    each whose header or the preset gives one (:mod:`.headers`),
    after the ``columns`` renames (matched like the aliases: case and
    surrounding spaces ignored) or the preset ``columns`` names."""
    preset = None
    if isinstance(columns, str):
        if columns not in PRESETS:
            raise ValidationError(f"columns={columns!r} must be a mapping of renames or a preset "
                                  f"of TI's tools: {preset_names()}")
        preset, columns = PRESETS[columns], None
    elif not columns:
        found = detect_preset(list(raw))
        preset = PRESETS[found] if found else None
    lower = {k.strip().lower(): k for k in raw}
    renames = {}
    for old, new in dict(columns or {}).items():
        key, target = str(old).strip().lower(), str(new).strip().lower()
        if key not in lower:
            raise FileFormatError(f"{name}: the columns mapping renames {old!r}, which the table "
                                  f"does not have (columns present: {sorted(raw)})")
        canon = next((c for c, aliases in _ALIASES.items() if target in aliases), None)
        if canon is None:
            raise FileFormatError(f"{name}: the columns mapping renames {old!r} to {new!r}, "
                                  f"which is not a column name this reader knows "
                                  f"({sorted(_ALIASES)} or their aliases)")
        renames[key] = canon
    out: dict[str, NDArray] = {}
    origin: dict[str, str] = {}
    units: dict[str, str] = {}
    for key, original in lower.items():
        base, unit = header_unit(original)
        canon, preset_unit = _target(key, base, renames, preset)
        if canon is None:
            continue
        if canon in origin:
            raise FileFormatError(f"{name}: columns {[origin[canon], original]} all mean "
                                  f"{canon}; keep one (or rename the others with a columns "
                                  "mapping, mmsnap import table --columns)")
        origin[canon], out[canon] = original, raw[original]
        unit = unit or preset_unit
        if unit is not None and canon in QUANTITY:
            unit_factor(canon, unit, original, name)          # a unit of the quantity
            units[canon] = unit
    return out, units


def _kind(cols: dict, coordinates: str, name: str, present: list[str]) -> str:
    have = lambda req: [c for c in req if c not in cols]
    if coordinates == "auto":
        if not have(CARTESIAN_COLUMNS):
            return "cartesian"
        if not have(SPHERICAL_COLUMNS):
            return "spherical"
        cart, sph = have(CARTESIAN_COLUMNS), have(SPHERICAL_COLUMNS)
        raise FileFormatError(f"{name}: missing columns: Cartesian points need {cart} "
                              f"({_short(cart)}), spherical points need {sph} ({_short(sph)}) "
                              f"(columns present: {present}){columns_hint(present)}")
    required = CARTESIAN_COLUMNS if coordinates == "cartesian" else SPHERICAL_COLUMNS
    if have(required):
        raise FileFormatError(f"{name}: missing {coordinates} columns {have(required)} "
                              f"({_short(have(required))}) (columns present: {present})"
                              f"{columns_hint(present)}")
    return coordinates


def columns_hint(present: list[str]) -> str:
    """How to name a table's columns: a columns mapping, or the preset of
    the TI tool whose headers the table holds most of."""
    preset = suggest_preset(present)
    tool = (f", or columns={preset!r} (--columns {preset}) for the table of "
            f"{PRESETS[preset].tool}" if preset else "")
    return (f"; name a column with a columns mapping, e.g. columns={{'HEADER': 'x'}} (mmsnap "
            f"import table --columns 'HEADER=x', repeat per column){tool}")


def _short(canonical: list[str]) -> str:
    """The names a log usually has for these columns: ``or z, doppler``."""
    return "or " + ", ".join(_ALIASES[c][1] for c in canonical)


class _Rows:
    """Names a table row for an error: ``line N`` of a CSV file (counted only
    when an error needs it: blank and ``#`` lines are skipped as pandas
    does), else ``row N`` (0-based, a DataFrame's position)."""

    def __init__(self, source: Any):
        self._path = (Path(source) if isinstance(source, (str, os.PathLike))
                      and Path(source).suffix.lower() not in (".npy", ".npz") else None)
        self._lines: list[int] | None = None

    def __call__(self, row: int) -> str:
        if self._path is None:
            return f"row {row}"
        if self._lines is None:
            text = self._path.read_text(errors="replace").splitlines()
            self._lines = [k for k, line in enumerate(text, start=1)
                           if line.strip() and not line.lstrip().startswith("#")]
        k = row + 1                                   # the header is the first line kept
        return f"line {self._lines[k]}" if k < len(self._lines) else f"row {row}"


def _scalar(value: Any) -> Any:
    """A NumPy scalar as the plain Python value (for ``repr`` in messages)."""
    return value.item() if isinstance(value, np.generic) else value


def _first_bad_value(column: NDArray) -> int:
    """Index of the first entry that is not a number (-1 if none)."""
    for i, value in enumerate(np.asarray(column, dtype=object).ravel()):
        try:
            float(value)
        except (TypeError, ValueError):
            return i
    return -1


def _float(cols: dict, key: str, name: str, where: _Rows) -> NDArray:
    try:
        return np.asarray(cols[key], dtype=float)
    except (TypeError, ValueError):
        bad = _first_bad_value(cols[key])
        value = np.asarray(cols[key], dtype=object).ravel()[bad] if bad >= 0 else None
        at = f"; {where(bad)} holds {_scalar(value)!r}" if bad >= 0 else ""
        raise FileFormatError(f"{name}: column {key} must be numeric{at}") from None


def _checked(values: NDArray, key: str, rows: NDArray, name: str, where: _Rows) -> NDArray:
    """``values`` (the column ``key`` at ``rows``) if finite, else an error
    naming the first row that is not (an empty CSV cell is NaN)."""
    if key in ("snr_db", "noise_db"):
        return values                               # side info may be missing (NaN)
    if not np.all(np.isfinite(values)):
        j = int(np.flatnonzero(~np.isfinite(values))[0])
        raise FileFormatError(f"{name}: column {key} must be finite; point {j} "
                              f"({where(rows[j])}) holds {float(values[j])!r}")
    limit = _LIMITS.get(key)
    if limit is not None and values.size and np.max(np.abs(values)) > limit:
        j = int(np.argmax(np.abs(values)))
        raise FileFormatError(f"{name}: column {key} must lie within +-{limit:g}; point {j} "
                              f"({where(rows[j])}) holds {float(values[j])!r}")
    return values


#: The largest frame number a table may give: every frame number up to it is an
#: exact float64 (the CSV reader's numbers) and an int64.
MAX_FRAME = 2 ** 53


def _frames_from_time(time_s: NDArray, frame_period_s: float | None, name: str) -> NDArray:
    if frame_period_s is None:
        _, inverse = np.unique(time_s, return_inverse=True)
        return inverse.astype(np.int64)
    with np.errstate(over="ignore", invalid="ignore"):
        frame = np.round((time_s - time_s.min()) / frame_period_s)
    if frame.size and not (np.all(np.isfinite(frame)) and frame.max() <= MAX_FRAME):
        span = float(time_s.max()) - float(time_s.min())
        raise FileFormatError(f"{name}: the time stamps span {span:.6g} s, "
                              f"{span / frame_period_s:.3g} frames of frame_period_s="
                              f"{frame_period_s!r} s (at most 2^53); check the time stamps and "
                              "the frame period (mmsnap import --frame-period)")
    return frame.astype(np.int64)


def _frame_column(cols: dict, rows: NDArray, get, name: str, where: "_Rows") -> NDArray:
    frame = get("frame")
    bad = np.flatnonzero((frame != np.round(frame)) | (np.abs(frame) > MAX_FRAME))
    if bad.size:
        row = rows[bad[0]]
        raise FileFormatError(f"{name}: column frame must hold integers; {where(row)} holds "
                              f"{_scalar(cols['frame'][row])!r} (frame numbers lie within "
                              "+-2^53)")
    return frame.astype(np.int64)


def _name_of(value: Any) -> str:
    """A node name from a cell: a number read from the text as written
    (``1``, not the float ``1.0`` the CSV parser made of it, so that
    ``--mount 1=...`` finds it)."""
    if isinstance(value, float) and value.is_integer() and abs(value) < 2 ** 53:
        return str(int(value))
    return str(value).strip()


def _node_names(column: NDArray, name: str, where: "_Rows") -> NDArray:
    """The node column as strings; an empty cell is an error naming its line."""
    values = np.asarray(column)
    if values.dtype.kind in "US":
        text = np.char.strip(values.astype(str))
        empty = np.flatnonzero(text == "").tolist()
    else:
        values = values.astype(object)
        empty = [i for i, v in enumerate(values)
                 if v is None or (isinstance(v, float) and not np.isfinite(v))
                 or (isinstance(v, str) and not v.strip())]
        text = np.array([_name_of(_scalar(v)) for v in values], dtype=str)
    if empty:
        raise FileFormatError(f"{name}: column node is empty at {where(empty[0])}; every point "
                              "needs its node's name")
    return text


def _units(header: dict[str, str], *, degrees: bool, time_unit: str,
           snr_unit: str | None, name: str) -> tuple[dict[str, float], str]:
    """The factor to SI of each column and the SNR column's unit: a unit in
    the header (or the preset) first, then the options; an option that
    contradicts the header is an error."""
    written = header.get("snr_db")
    scale = {k: unit_factor(k, u, k, name) for k, u in header.items() if k != "snr_db"}
    if scale.get("noise_db", 1.0) is None:
        raise FileFormatError(f"{name}: a noise column in linear units is not read (dB)")
    deg = np.pi / 180
    for key in ("azimuth_rad", "elevation_rad"):
        if degrees and scale.get(key, deg) != deg:
            raise FileFormatError(f"{name}: degrees=True (--degrees), but the header of "
                                  f"{key} says radians")
        scale.setdefault(key, deg if degrees else 1.0)
    if "time_s" in scale and time_unit != "s" and scale["time_s"] != _TIME_UNITS[time_unit]:
        raise FileFormatError(f"{name}: time_unit={time_unit!r} (--time-unit), but the header "
                              f"of time_s gives another unit")
    scale.setdefault("time_s", _TIME_UNITS[time_unit])
    if written and snr_unit and snr_unit != written:
        raise FileFormatError(f"{name}: snr_unit={snr_unit!r} (--snr-unit), but the header of "
                              f"the SNR column says {written}")
    snr = written or snr_unit or "db"
    scale.setdefault("noise_db", 0.1 if snr == "0.1db" else 1.0)    # the same side info
    return scale, snr


def _angles(get, scale: dict, name: str, rows: NDArray, where: _Rows) -> tuple[NDArray, NDArray]:
    """The azimuth and elevation columns in radians: a value beyond +-pi read
    as radians is an error naming ``degrees``; read as degrees, angles that
    all lie within +-pi/2 degrees (a radar sees tens of degrees) warn."""
    az, el = get("azimuth_rad"), get("elevation_rad")
    for key, values in (("azimuth_rad", az), ("elevation_rad", el)):
        if scale[key] == 1.0 and values.size and np.max(np.abs(values)) > np.pi:
            j = int(np.argmax(np.abs(values)))
            raise FileFormatError(
                f"{name}: column {key} holds {float(values[j])!r} at {where(rows[j])}, "
                "beyond +-pi: not an angle in radians; degrees? (degrees=True, mmsnap "
                "import table --degrees)")
    degrees = scale["azimuth_rad"] != 1.0 and scale["elevation_rad"] != 1.0
    if degrees and az.size >= 10 and max(np.max(np.abs(az)), np.max(np.abs(el))) \
            <= np.deg2rad(np.pi / 2):
        warnings.warn(f"{name}: every azimuth and elevation lies within +-{np.pi / 2:.4g} "
                      "degrees, read as degrees (degrees=True, --degrees): radians? a radar "
                      "sees tens of degrees", MmsnapWarning, stacklevel=4)
    return az, el


def _snr(values: NDArray, unit: str, name: str) -> NDArray:
    """The SNR column in dB from ``unit``; values beyond any radar's SNR in
    dB are an error naming the units it may be in."""
    if unit == "0.1db":
        values = values * 0.1
    elif unit == "linear":
        with np.errstate(divide="ignore", invalid="ignore"):
            values = np.where(values > 0, 10.0 * np.log10(values), np.nan)
    finite = values[np.isfinite(values)]
    if finite.size and (np.median(finite) > MAX_MEDIAN_SNR_DB or finite.max() > MAX_SNR_DB):
        raise FileFormatError(
            f"{name}: column snr holds SNRs up to {finite.max():.6g} dB (median "
            f"{np.median(finite):.6g} dB) read as snr_unit={unit!r}, beyond any radar's "
            f"(TI's boards: a median below {MAX_MEDIAN_SNR_DB:g} dB, at most about "
            f"{MAX_SNR_DB:g} dB); TI's side info counts steps of 0.1 dB (snr_unit='0.1db', "
            "mmsnap import table --snr-unit 0.1db), the people-tracking demos a linear ratio "
            "(--snr-unit linear)")
    return values


def _cloud(cols: dict, rows: NDArray, kind: str, *, name: str, scale: dict, snr_unit: str,
           frame_period_s: float | None, where: _Rows) -> PointCloud3D:
    get = lambda k: _checked(_float(cols, k, name, where)[rows] * scale.get(k, 1.0), k, rows,
                             name, where)
    time = get("time_s") if "time_s" in cols else None
    if time is not None and time.size and np.max(np.abs(time)) > _MAX_TIME_S:
        j = int(np.argmax(np.abs(time)))
        ms = (" (milliseconds, as TI's visualizer stamps? time_unit='ms', --time-unit ms, or "
              "--columns visualizer)" if np.max(np.abs(time)) * 1e-3 <= _MAX_TIME_S else "")
        raise FileFormatError(f"{name}: column time_s holds {float(time[j])!r} s at "
                              f"{where(rows[j])}; time stamps must lie within +-1e12 s "
                              f"(check --time-unit){ms}")
    if "frame" in cols:
        frame = _frame_column(cols, rows, get, name, where)
    else:
        frame = _frames_from_time(time, frame_period_s, name)
    if kind == "cartesian":
        x, y, z = get("x_m"), get("y_m"), get("z_m")
    else:
        x, y, z = spherical_to_cartesian(get("range_m"), *_angles(get, scale, name, rows,
                                                                    where)).T
    opt = {k: get(k) for k in ("snr_db", "noise_db") if k in cols}
    if "snr_db" in opt:
        opt["snr_db"] = _snr(opt["snr_db"], snr_unit, name)
    try:
        return PointCloud3D(frame=frame, x_m=x, y_m=y, z_m=z, doppler_mps=get("doppler_mps"),
                            time_s=time, **opt)
    except ValidationError as exc:
        raise FileFormatError(f"{name}: {exc}") from None


def read_point_tables(source: Any, *, coordinates: Literal["auto", "cartesian",
                                                           "spherical"] = "auto",
                      columns: Mapping[str, str] | str | None = None, degrees: bool = False,
                      time_unit: Literal["s", "ms", "us", "ns"] = "s",
                      frame_period_s: float | None = None,
                      default_node: str = "S1",
                      snr_unit: Literal["db", "0.1db", "linear"] | None = None
                      ) -> dict[str, PointCloud3D]:
    """Read a point table (module docstring) into node name -> cloud.

    coordinates : which columns to use (``"auto"``: Cartesian if present,
    else spherical). columns : renames, e.g. ``{"Doppler": "doppler_mps"}``,
    or the name of a TI tool's header set (:data:`.headers.PRESETS`; the
    mmWave SDK example parser's header is recognised without it). A unit
    written in a header (``X (m)``, ``Azimuth (deg)``, ``Timestamp (ms)``)
    is read (:mod:`.headers`). The options below apply to the columns whose
    header gives no unit; one that contradicts a header is an error.
    degrees : angles are in degrees (an angle beyond +-pi without it is an
    error; with it, angles all within +-pi/2 warn). time_unit : of the
    time-stamp column. snr_unit : of the SNR column (:data:`SNR_UNITS`,
    default dB; SNRs beyond any radar's in dB are an error).
    frame_period_s : numbers frames from time stamps as ``round((t - t0) /
    frame_period_s)`` when there is no frame column (else the distinct time
    stamps are numbered in order). default_node : the node of a table
    without a node column.
    Raises :class:`FileFormatError` naming the missing columns and the table,
    or a value that is not a finite number (or a frame that is not an integer)
    with its line in a CSV file (its row in a DataFrame).
    """
    if coordinates not in ("auto", "cartesian", "spherical"):
        raise ValidationError(f"coordinates={coordinates!r} must be 'auto', 'cartesian' or "
                              "'spherical'")
    if time_unit not in _TIME_UNITS:
        raise ValidationError(f"time_unit={time_unit!r} must be one of {sorted(_TIME_UNITS)}")
    if snr_unit is not None and snr_unit not in SNR_UNITS:
        raise ValidationError(f"snr_unit={snr_unit!r} must be one of {list(SNR_UNITS)}")
    if frame_period_s is not None and not (isinstance(frame_period_s, (int, float))
                                           and np.isfinite(frame_period_s)
                                           and frame_period_s > 0):
        raise ValidationError(f"frame_period_s={frame_period_s!r} must be a finite number > 0")
    name = str(source) if isinstance(source, (str, os.PathLike)) else "point table"
    raw = _checked_columns(_as_columns(source, name), name)
    cols, header_units = _canonical(raw, columns, name)
    scale, snr = _units(header_units, degrees=degrees, time_unit=time_unit, snr_unit=snr_unit,
                        name=name)
    present = sorted(raw)
    if "frame" not in cols and "time_s" not in cols:
        raise FileFormatError(f"{name}: missing columns: a frame number (frame) or a time "
                              f"stamp (time_s) is needed (columns present: {present})"
                              f"{columns_hint(present)}")
    kind = _kind(cols, coordinates, name, present)
    n = len(next(iter(raw.values())))
    opts = dict(name=name, scale=scale, snr_unit=snr, frame_period_s=frame_period_s,
                where=_Rows(source))
    if "node" not in cols:
        return {default_node: _cloud(cols, _in_line(cols, np.arange(n), default_node, opts),
                                     kind, **opts)}
    nodes = _node_names(cols["node"], name, opts["where"])
    return {str(node): _cloud(cols, _in_line(cols, np.flatnonzero(nodes == node), node, opts),
                              kind, **opts) for node in dict.fromkeys(nodes.tolist())}


def _in_line(cols: dict, rows: NDArray, node: str, opts: dict) -> NDArray:
    """``rows`` of one node without those whose frame numbers are out of line
    (:func:`~mmsnap_graph._validation.outlying_frames`: a stray -5 among
    frames 0-104 would become the node's origin), which are left out with a
    warning naming them and their lines."""
    if "frame" not in cols or rows.size < 3:
        return rows
    frame = np.asarray(cols["frame"])[rows]
    if frame.dtype.kind not in "iuf" or not np.all(np.isfinite(frame)) \
            or np.any(np.abs(frame) > MAX_FRAME) or np.any(frame != np.round(frame)):
        return rows                                     # _cloud names the bad cell
    out = outlying_frames(frame.astype(np.int64))
    if not out.any():
        return rows
    bad = rows[out]
    shown = ", ".join(f"{int(frame[out][i])} at {opts['where'](r)}" for i, r in
                      enumerate(bad[:5])) + (", ..." if bad.size > 5 else "")
    warnings.warn(f"{opts['name']}: node {node}: {bad.size} row(s) hold frame numbers out of "
                  f"line with the node's other frames ({shown}); left out, not used as the "
                  "origin of its frame clock", MmsnapWarning, stacklevel=3)
    return rows[~out]


def read_point_table(source: Any, **options) -> PointCloud3D:
    """Read a one-radar point table (:func:`read_point_tables`, same options)."""
    clouds = read_point_tables(source, **options)
    if len(clouds) != 1:
        raise FileFormatError(f"the table holds {len(clouds)} nodes {sorted(clouds)}; read it "
                              "with read_point_tables (mmsnap import table --table FILE)")
    return next(iter(clouds.values()))
