"""The track-matching settings of a calibration, in seconds and metres, with
their defaults and checks (no GTSAM: the command line reads them).

:func:`~mmsnap_graph.calibration.pairwise.matching.match_tracks` and
:func:`~mmsnap_graph.calibration.network.calibrate_recording` take a
:class:`MatchingOptions`; ``mmsnap calibrate`` builds one from its options and
the ``[matching]`` table of its ``--config`` file (docs/CALIBRATION.md,
"Matching gate and thresholds in seconds").
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Literal

import numpy as np

from ...errors import ValidationError
from .closed_form import DEFAULT_MIN_COMMON_FRAMES, DEFAULT_MIN_SPREAD_M

__all__ = ["DEFAULT_MAX_LAG_S", "DEFAULT_MIN_COMMON_S", "DEFAULT_MIN_SPREAD_M",
           "DEFAULT_MAX_RMSE_M", "DEFAULT_INLIER_GATE_M", "DEFAULT_GATE_PROBABILITY",
           "MATCHING_UNITS", "MatchingOptions"]

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

#: Unit and range of each numeric setting (the error message says it).
MATCHING_UNITS: dict[str, str] = {
    "max_lag_s": "s, >= 0", "min_common_s": "s, >= 0", "min_spread_m": "m, >= 0",
    "max_rmse_m": "m, > 0", "inlier_gate_m": "m, > 0", "gate_probability": "in (0, 1)",
    "lag_min_improvement": ">= 0", "lag_ambiguity": ">= 0",
}
_CHOICES = {"covariance": ("residual", "sandwich"), "autocorrelation": ("auto", "none")}
#: Largest frame count the thresholds in seconds turn into.
_MAX_FRAMES = 2.0 ** 62


def _in_range(name: str, v: float) -> bool:
    if name == "gate_probability":
        return 0.0 < v < 1.0
    if name in ("max_rmse_m", "inlier_gate_m"):
        return v > 0.0
    return v >= 0.0


@dataclass(frozen=True, kw_only=True, slots=True)
class MatchingOptions:
    """How two nodes' tracks are matched (:func:`match_tracks`).

    max_lag_s : lags up to this either way are searched, in whole frames.
    min_common_s : track pairs that share less than this (and at least 5
        frames) are skipped.
    min_spread_m : the shared target must move this far in each node's
        tracks (as :func:`closed_form_calibration`).
    max_rmse_m : a final track RMSE above this means the tracks are not one
        target.
    inlier_gate_m : without track covariances, a frame pair supports a pose
        when b's point lands within this distance of a's point.
    gate_probability : with covariances on both sides (EKF tracks), the
        chi-square(2) gate probability.
    lag_min_improvement : a nonzero lag is reported only if its inlier RMSE
        is at least this fraction below lag 0's with at least 95% of its
        support.
    lag_ambiguity : other lags with 95% of the chosen lag's support and an
        inlier RMSE within this fraction of its make the lag ambiguous (a
        walk along a circle): the covariance is widened by the spread of
        their poses when they differ from the chosen one by more than 3
        sigma.
    covariance, autocorrelation : the closed form's pose covariance
        (:func:`closed_form_calibration`).

    A bad value raises :class:`~mmsnap_graph.errors.ValidationError` naming
    the field, the value and the range it must lie in.
    """

    max_lag_s: float = DEFAULT_MAX_LAG_S
    min_common_s: float = DEFAULT_MIN_COMMON_S
    min_spread_m: float = DEFAULT_MIN_SPREAD_M
    max_rmse_m: float = DEFAULT_MAX_RMSE_M
    inlier_gate_m: float = DEFAULT_INLIER_GATE_M
    gate_probability: float = DEFAULT_GATE_PROBABILITY
    lag_min_improvement: float = 0.05
    lag_ambiguity: float = 0.15
    covariance: Literal["residual", "sandwich"] = "residual"
    autocorrelation: Literal["auto", "none"] = "auto"

    def __post_init__(self) -> None:
        for name, unit in MATCHING_UNITS.items():
            value = getattr(self, name)
            bad = isinstance(value, bool)
            try:
                v = float(value)
            except (TypeError, ValueError):
                bad, v = True, math.nan
            if bad or not math.isfinite(v) or not _in_range(name, v):
                raise ValidationError(f"{name} must be a finite number ({unit}), got {value!r}")
            object.__setattr__(self, name, v)
        for name, choices in _CHOICES.items():
            if getattr(self, name) not in choices:
                raise ValidationError(f"{name}={getattr(self, name)!r} must be one of "
                                      f"{', '.join(map(repr, choices))}")

    def frame_counts(self, frame_period_s: float) -> tuple[int, int]:
        """The lag window and the minimum overlap in frames at
        ``frame_period_s`` (the overlap is at least
        :data:`DEFAULT_MIN_COMMON_FRAMES` frames)."""
        if isinstance(frame_period_s, bool) or not (
                isinstance(frame_period_s, (int, float, np.floating))
                and math.isfinite(frame_period_s) and frame_period_s > 0):
            raise ValidationError(f"frame_period_s must be finite and > 0, got "
                                  f"{frame_period_s!r}")
        # Clipped: 1e308 s in frames is no longer a finite integer (the lag
        # search is bounded by the recording's frames anyway).
        lag = int(min(np.round(self.max_lag_s / frame_period_s), _MAX_FRAMES))
        common = max(int(min(np.ceil(self.min_common_s / frame_period_s - 1e-9), _MAX_FRAMES)),
                     DEFAULT_MIN_COMMON_FRAMES)
        return lag, common

    def describe(self) -> str:
        """The thresholds as ``name=value unit`` (for a failure message)."""
        units = {"_s": " s", "_m": " m"}
        return ", ".join(f"{f.name}={getattr(self, f.name):g}{units.get(f.name[-2:], '')}"
                         for f in fields(self) if f.name in MATCHING_UNITS
                         and f.name not in ("lag_min_improvement", "lag_ambiguity"))
