"""FusionOptions and RobustOptions: frozen, keyword-only, validated once."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mmsnap_graph.errors import ValidationError
from mmsnap_graph.fusion import LevenbergMarquardtSettings
from mmsnap_graph.fusion.options import (DEFAULT_OPTIONS, FusionOptions, NetworkCalibration,
                                         RobustOptions, robust_options)

from _fuzz import assert_rejected


@pytest.mark.parametrize("kwargs, match", [
    ({"covariance": "exact"}, "covariance must be 'laplace' or 'grid'"),
    ({"covariance": "both"}, "covariance must be 'laplace' or 'grid'"),
    ({"solver": "batch"}, "'batch' is now called 'vectorized'"),
    ({"grid_points_per_axis": 0}, "grid_points_per_axis=0 must be an integer >= 1"),
    ({"chunk_size": 8.0}, "chunk_size=8.0 must be an integer, got float"),
    ({"step_tolerance": -1.0}, "step_tolerance must be a positive finite number"),
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


def test_network_calibration_checks_its_parts_and_is_read_only():
    poses = {"S1": [0.0, 0.0, 0.0], "S2": np.array([1.0, 2.0, 0.5])}
    cal = NetworkCalibration(node_poses=poses, time_offset_s={"S2": -0.1}, range_offset_m=0.05)
    assert cal.node_poses["S2"].tolist() == [1.0, 2.0, 0.5]
    poses["S2"][0] = 9.0  # the caller's mapping and arrays are copied
    assert cal.node_poses["S2"][0] == 1.0
    with pytest.raises(TypeError):
        cal.node_poses["S3"] = np.zeros(3)
    with pytest.raises(ValueError):
        cal.node_poses["S1"][0] = 1.0
    with pytest.raises(dataclasses.FrozenInstanceError):
        cal.range_offset_m = 0.0
    with pytest.raises(TypeError):
        NetworkCalibration({"S1": [0, 0, 0]})  # keyword-only
    assert NetworkCalibration().node_poses is None


@pytest.mark.parametrize("kwargs, match", [
    ({"node_poses": [[0, 0, 0]]}, "node_poses must be a mapping node name"),
    ({"node_poses": {"S1": [0, 0]}}, r"pose of S1 must have shape \(3,\)"),
    ({"node_poses": {"S1": [0, np.nan, 0]}}, "pose of S1"),
    ({"pose_covariances": np.eye(3)[None]}, "pose_covariances must be a mapping"),
    ({"time_offset_s": {"S2": float("inf")}}, r"time_offset_s\['S2'\]=inf must be a finite"),
    ({"time_offset_s": {"S2": "0.1"}}, "seconds"),
    ({"range_offset_m": 50.0}, "range_offset_m=50.0 must be finite metres within"),
    ({"range_offset_m": True}, "range_offset_m=True"),
])
def test_network_calibration_rejects_bad_parts(kwargs, match):
    with pytest.raises(ValidationError, match=match):
        NetworkCalibration(**kwargs)
