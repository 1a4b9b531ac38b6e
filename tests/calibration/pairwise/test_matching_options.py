"""MatchingOptions: the track matching's thresholds in seconds and metres,
checked once when made."""

from __future__ import annotations

import dataclasses

import pytest

from mmsnap_graph import MatchingOptions as TopMatchingOptions
from mmsnap_graph.calibration import MatchingOptions
from mmsnap_graph.errors import ValidationError


@pytest.mark.parametrize("period_s, frames", [
    (0.150, (2, 5)), (0.05, (6, 10)), (1 / 30, (9, 15)),
    (0.2, (1, 5)),  # 0.3 s is 1.5 frames: 1.4999... in floating point
])
def test_seconds_become_frames_at_the_recording_period(period_s, frames):
    assert MatchingOptions().frame_counts(period_s) == frames


def test_at_least_five_common_frames_and_rounded_lags():
    o = MatchingOptions(max_lag_s=0.25, min_common_s=0.0)
    assert o.frame_counts(0.1) == (2, 5)  # 2.5 frames rounds to even
    assert MatchingOptions(max_lag_s=0.0).frame_counts(0.1)[0] == 0


@pytest.mark.parametrize("period_s", [0.0, -0.1, float("nan"), float("inf"), True, None])
def test_a_bad_frame_period_is_named(period_s):
    with pytest.raises(ValidationError, match="frame_period_s"):
        MatchingOptions().frame_counts(period_s)


@pytest.mark.parametrize("field, value, unit", [
    ("max_lag_s", -0.1, "s, >= 0"), ("min_common_s", float("nan"), "s, >= 0"),
    ("min_spread_m", "far", "m, >= 0"), ("max_rmse_m", 0.0, "m, > 0"),
    ("inlier_gate_m", True, "m, > 0"), ("gate_probability", 1.0, "in (0, 1)"),
    ("lag_min_improvement", -0.01, ">= 0"), ("lag_ambiguity", float("inf"), ">= 0"),
])
def test_a_bad_threshold_names_field_value_and_range(field, value, unit):
    with pytest.raises(ValidationError) as err:
        MatchingOptions(**{field: value})
    assert str(err.value) == f"{field} must be a finite number ({unit}), got {value!r}"


def test_choices_floats_frozen_and_the_failure_text():
    with pytest.raises(ValidationError, match="covariance='model'"):
        MatchingOptions(covariance="model")
    with pytest.raises(ValidationError, match="autocorrelation='off'"):
        MatchingOptions(autocorrelation="off")
    o = MatchingOptions(max_lag_s=1, inlier_gate_m=2)
    assert type(o.max_lag_s) is float and o == MatchingOptions(max_lag_s=1.0, inlier_gate_m=2.0)
    with pytest.raises(dataclasses.FrozenInstanceError):
        o.max_lag_s = 0.5
    assert TopMatchingOptions is MatchingOptions
    assert MatchingOptions().describe() == (
        "max_lag_s=0.3 s, min_common_s=0.5 s, min_spread_m=0.2 m, max_rmse_m=1 m, "
        "inlier_gate_m=0.5 m, gate_probability=0.997")
