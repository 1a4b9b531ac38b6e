"""The track-matching thresholds of a calibration, in seconds and metres, with
their defaults and checks (no GTSAM: the command line reads them).

:func:`~mmsnap_graph.calibration.pairwise.matching.match_tracks` and
:func:`~mmsnap_graph.calibration.network.calibrate_recording` take them as
keywords; ``mmsnap calibrate`` as options and as the ``[matching]`` table of
its ``--config`` file (docs/CALIBRATION.md, "Matching gate and thresholds in
seconds").
"""

from __future__ import annotations

import math
from typing import Any

from ...errors import ValidationError
from .closed_form import DEFAULT_MIN_SPREAD_M

__all__ = ["DEFAULT_MAX_LAG_S", "DEFAULT_MIN_COMMON_S", "DEFAULT_MIN_SPREAD_M",
           "DEFAULT_MAX_RMSE_M", "DEFAULT_INLIER_GATE_M", "DEFAULT_GATE_PROBABILITY",
           "MATCHING_DEFAULTS", "MATCHING_UNITS", "check_matching_options"]

#: Lags up to this either way are searched (s).
DEFAULT_MAX_LAG_S = 0.3
#: Track pairs sharing less than this (and at least 5 frames) are skipped (s).
DEFAULT_MIN_COMMON_S = 0.5
#: A final track RMSE above this means the tracks are not one target (m).
DEFAULT_MAX_RMSE_M = 1.0
#: Without track covariances: the distance (m) within which a frame pair
#: supports a pose. With them: the chi-square(2) gate probability.
DEFAULT_INLIER_GATE_M = 0.5
DEFAULT_GATE_PROBABILITY = 0.997

#: Every matching threshold and its default, in the order the docs list them.
MATCHING_DEFAULTS: dict[str, float] = {
    "max_lag_s": DEFAULT_MAX_LAG_S,
    "min_common_s": DEFAULT_MIN_COMMON_S,
    "min_spread_m": DEFAULT_MIN_SPREAD_M,
    "max_rmse_m": DEFAULT_MAX_RMSE_M,
    "inlier_gate_m": DEFAULT_INLIER_GATE_M,
    "gate_probability": DEFAULT_GATE_PROBABILITY,
}
#: Unit of each threshold, and the range it must lie in.
MATCHING_UNITS: dict[str, str] = {
    "max_lag_s": "s, >= 0", "min_common_s": "s, >= 0", "min_spread_m": "m, >= 0",
    "max_rmse_m": "m, > 0", "inlier_gate_m": "m, > 0", "gate_probability": "in (0, 1)",
}


def _ok(name: str, v: float) -> bool:
    if name == "gate_probability":
        return 0.0 < v < 1.0
    if name in ("max_rmse_m", "inlier_gate_m"):
        return v > 0.0
    return v >= 0.0


def check_matching_options(**options: Any) -> dict[str, float]:
    """The given thresholds (names of :data:`MATCHING_DEFAULTS`; a None value
    is left out: the default applies) as floats. Raises
    :class:`~mmsnap_graph.errors.ValidationError` naming the field, its
    value and the range it must lie in."""
    out: dict[str, float] = {}
    for name, value in options.items():
        if name not in MATCHING_DEFAULTS:
            raise ValidationError(f"unknown matching option {name!r} (known: "
                                  f"{', '.join(MATCHING_DEFAULTS)})")
        if value is None:
            continue
        bad = isinstance(value, bool)
        try:
            v = float(value)
        except (TypeError, ValueError):
            bad = True
        if bad or not math.isfinite(v) or not _ok(name, v):
            raise ValidationError(f"{name} must be a finite number ({MATCHING_UNITS[name]}), "
                                  f"got {value!r}")
        out[name] = v
    return out
