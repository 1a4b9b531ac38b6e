"""Column headers of point tables: units written in the header, and the
header sets TI's own tools write (presets).

A header may carry its unit, as spreadsheets and TI's visualizers write
them: ``X (m)``, ``Doppler (m/s)``, ``Azimuth [deg]``, ``Timestamp (ms)``,
``SNR (0.1 dB)``. :func:`header_unit` splits such a name into the name and
the factor to SI (radians, seconds, dB); a unit that does not fit the
quantity (``X (ft)``, ``Doppler (deg)``) is an error naming the column.

:data:`PRESETS` are the header sets of TI's tools, by name
(``mmsnap import table --columns NAME``):

- ``visualizer``: the point cloud of TI's Industrial / Applications
  Visualizer (the mmWave Radar Toolbox's, which also runs the 3D people
  tracking demos): ``frameNum``, ``timestamp`` (milliseconds, its
  ``time.time() * 1000``), ``X, Y, Z`` (m), ``Doppler`` (m/s), ``SNR``,
  ``Noise`` (dB), ``Track index`` (not read), with or without units in the
  names; its replay JSON is read directly (:mod:`.replay`);
- ``sdk-script``: the CSV of the mmWave SDK's example parser
  ``mmw_demo_example_script.py`` (the out-of-box demo's recorded UART
  stream): ``frame, DetObj#, x, y, z, v, snr, noise``, the SNR and noise in
  TI's steps of 0.1 dB. Its header is recognised without ``--columns``.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from ...errors import FileFormatError

__all__ = ["PRESETS", "Preset", "header_unit", "unit_factor", "detect_preset", "suggest_preset",
           "preset_names"]

#: Units by quantity: the factor from the unit to the library's (m, m/s,
#: rad, s, dB). Keys are lower case with spaces removed.
_UNITS = {
    "length": {"m": 1.0, "cm": 0.01, "mm": 0.001, "meter": 1.0, "meters": 1.0, "metres": 1.0},
    "speed": {"m/s": 1.0, "mps": 1.0, "cm/s": 0.01, "km/h": 1 / 3.6, "kmh": 1 / 3.6},
    "angle": {"rad": 1.0, "radian": 1.0, "radians": 1.0, "deg": np.pi / 180,
              "degree": np.pi / 180, "degrees": np.pi / 180, "\u00b0": np.pi / 180},
    "time": {"s": 1.0, "sec": 1.0, "ms": 1e-3, "us": 1e-6, "\u00b5s": 1e-6, "ns": 1e-9},
    "level": {"db": 1.0, "0.1db": 0.1, "linear": None},     # a power ratio: 10 log10
}
#: The quantity of each canonical column (those without one take no unit).
QUANTITY = {"x_m": "length", "y_m": "length", "z_m": "length", "range_m": "length",
            "doppler_mps": "speed", "azimuth_rad": "angle", "elevation_rad": "angle",
            "time_s": "time", "snr_db": "level", "noise_db": "level"}
_UNIT_IN_NAME = re.compile(r"^(?P<name>.*?)\s*[(\[](?P<unit>[^()\[\]]*)[)\]]\s*$")


def header_unit(header: str) -> tuple[str, str | None]:
    """``"X (m)"`` -> ``("x", "m")``: the name (lower case, stripped) and the
    unit written in brackets after it (lower case, spaces removed), or None."""
    match = _UNIT_IN_NAME.match(header.strip())
    if not match or not match["name"]:
        return header.strip().lower(), None
    return match["name"].lower(), match["unit"].replace(" ", "").lower()


def unit_factor(canonical: str, unit: str, header: str, name: str) -> float | None:
    """The factor from ``unit`` (written in the column ``header``) to the
    library's unit of ``canonical`` (None: a linear power ratio, taken to dB
    as ``10 log10``); an error when it does not fit."""
    quantity = QUANTITY.get(canonical)
    units = _UNITS.get(quantity, {})
    if unit not in units:
        known = sorted(units) if units else "none"
        raise FileFormatError(f"{name}: column {header!r} is in {unit!r}, which is not a unit of "
                              f"{canonical} (units read: {known}); rename the column with a "
                              "columns mapping (mmsnap import table --columns 'HEADER=COLUMN')")
    return units[unit]


@dataclass(frozen=True, kw_only=True, slots=True)
class Preset:
    """One header set of a TI tool: header (lower case, without unit) ->
    (canonical column or None = not read, its unit or None = the header's or
    the library's). ``signature`` : headers whose presence alone identifies
    the tool's table (recognised without ``--columns``); ``tool`` names it."""

    tool: str
    columns: dict
    signature: frozenset = frozenset()


PRESETS = {
    "visualizer": Preset(
        tool="TI's Industrial / Applications Visualizer (mmWave Radar Toolbox, 3D people "
             "tracking)",
        columns={"framenum": ("frame", None), "frame": ("frame", None),
                 "frame number": ("frame", None), "timestamp": ("time_s", "ms"),
                 "x": ("x_m", "m"), "y": ("y_m", "m"), "z": ("z_m", "m"),
                 "doppler": ("doppler_mps", "m/s"), "snr": ("snr_db", "db"),
                 "noise": ("noise_db", "db"), "track index": (None, None),
                 "track": (None, None)}),
    "sdk-script": Preset(
        tool="the mmWave SDK's example parser mmw_demo_example_script.py",
        columns={"frame": ("frame", None), "detobj#": (None, None), "x": ("x_m", "m"),
                 "y": ("y_m", "m"), "z": ("z_m", "m"), "v": ("doppler_mps", "m/s"),
                 "snr": ("snr_db", "0.1db"), "noise": ("noise_db", "0.1db")},
        signature=frozenset({"detobj#"})),
}


def preset_names() -> list[str]:
    return sorted(PRESETS)


def detect_preset(headers: list[str]) -> str | None:
    """The preset whose signature the headers hold (every header then one of
    its columns), or None."""
    names = {header_unit(h)[0] for h in headers}
    for key, preset in PRESETS.items():
        if preset.signature and preset.signature <= names and names <= set(preset.columns):
            return key
    return None


def suggest_preset(headers: list[str]) -> str | None:
    """The preset naming the most of these headers (at least three), or None."""
    names = {header_unit(h)[0] for h in headers}
    best = max(PRESETS, key=lambda k: len(names & set(PRESETS[k].columns)))
    return best if len(names & set(PRESETS[best].columns)) >= 3 else None
