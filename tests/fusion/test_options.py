"""FusionOptions and RobustOptions: frozen, keyword-only, validated once."""

from __future__ import annotations

import dataclasses

import pytest

from mmsnap_graph.errors import ValidationError
from mmsnap_graph.fusion import LevenbergMarquardtSettings
from mmsnap_graph.fusion.options import (DEFAULT_OPTIONS, FusionOptions, RobustOptions,
                                         robust_options)

from _fuzz import assert_rejected


@pytest.mark.parametrize("kwargs, match", [
    ({"covariance": "exact"}, "covariance must be 'laplace', 'grid', 'both'"),
    ({"solver": "batch"}, "'batch' is now called 'vectorized'"),
    ({"source": "cube"}, "source must be 'centroids', 'point_cloud'"),
    ({"grid_points_per_axis": 0}, "grid_points_per_axis=0 must be an integer >= 1"),
    ({"chunk_size": 8.0}, "chunk_size=8.0 must be an integer, got float"),
    ({"step_tolerance": -1.0}, "step_tolerance must be a positive finite number"),
    ({"gate_probability": 1.0}, r"gate_probability must be in \(0, 1\)"),
    ({"motion_check": "yes"}, "motion_check must be True, False or None"),
    ({"lm": {"max_iterations": 3}}, "lm must be a LevenbergMarquardtSettings"),
])
def test_fusion_options_are_validated(kwargs, match):
    with pytest.raises(ValidationError, match=match):
        FusionOptions(**kwargs)


def test_options_are_frozen_and_keyword_only():
    with pytest.raises(dataclasses.FrozenInstanceError):
        DEFAULT_OPTIONS.solver = "gtsam"
    with pytest.raises(TypeError):
        FusionOptions("laplace")  # noqa: the point is that it raises
    assert FusionOptions(solver="gtsam") == dataclasses.replace(DEFAULT_OPTIONS, solver="gtsam")


def test_a_kernel_name_is_shorthand_for_its_defaults():
    assert robust_options(None) is None
    gate = robust_options("gate")
    assert gate == RobustOptions(kernel="gate") and gate.kernel_pair is None
    huber = robust_options("huber")
    assert huber.kernel_pair == ("huber", 1.345) and huber.threshold == pytest.approx(16.266, abs=1e-3)
    assert robust_options(huber) is huber


@pytest.mark.parametrize("make, kwargs", [
    (FusionOptions, {"chunk_size": "8"}), (FusionOptions, {"newton_after": 2.5}),
    (FusionOptions, {"step_tolerance": True}), (FusionOptions, {"lm": {"max_iterations": 5}}),
    (LevenbergMarquardtSettings, {"max_iterations": 2.5}),
    (LevenbergMarquardtSettings, {"max_iterations": True}),
    (LevenbergMarquardtSettings, {"lambda_initial": float("nan")})])
def test_fusion_options_reject_scalars_of_the_wrong_type(make, kwargs):
    assert_rejected(make, **kwargs)
