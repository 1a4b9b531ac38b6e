"""JointOptions and AssociationOptions: the joint graph's settings, checked
once when made."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mmsnap_graph import JointOptions as TopJointOptions
from mmsnap_graph.calibration import (
    DEFAULT_ROBUST_K,
    POINT_JOINT_OPTIONS,
    AssociationOptions,
    JointOptions,
)
from mmsnap_graph.data.noise import MeasurementNoise
from mmsnap_graph.errors import ValidationError


def test_defaults_and_the_kernel_width():
    o = JointOptions()
    assert o.robust == "cauchy" and o.kernel_k == DEFAULT_ROBUST_K["cauchy"]
    assert JointOptions(robust="huber").kernel_k == DEFAULT_ROBUST_K["huber"]
    assert JointOptions(robust="huber", robust_k=2.0).kernel_k == 2.0
    assert JointOptions(robust=None).kernel_k is None
    assert o.state_prior_sigmas == (1e3, 1e3, 3.5, 3.5)
    assert TopJointOptions is JointOptions
    assert (POINT_JOINT_OPTIONS.motion, POINT_JOINT_OPTIONS.sigma_a_mps2,
            POINT_JOINT_OPTIONS.time_offsets) == (True, 3.0, True)


def test_values_are_normalised_and_frozen():
    o = JointOptions(state_prior_sigmas=np.array([10, 10, 2, 2]), max_iterations=np.int64(7),
                     robust_k=3)
    assert o.state_prior_sigmas == (10.0, 10.0, 2.0, 2.0)
    assert type(o.max_iterations) is int and o.max_iterations == 7
    assert type(o.robust_k) is float
    with pytest.raises(dataclasses.FrozenInstanceError):
        o.robust = None
    with pytest.raises(TypeError):
        JointOptions("cauchy")  # keyword-only


@pytest.mark.parametrize("field, value", [
    ("robust", "tukey"), ("motion_robust", "l2"),
    ("robust_k", 0.0), ("robust_k", float("nan")), ("sigma_a_mps2", -1.0),
    ("motion_robust_k", 0.0), ("max_pose_variance", float("inf")), ("max_pose_condition", 0),
    ("min_spread_m", -0.1), ("max_motion_gap_frames", 0), ("min_common_frames", 2.5),
    ("max_iterations", True), ("motion", "yes"), ("time_offsets", 1), ("presolve", None),
    ("state_covariances", "no"), ("state_prior_sigmas", (1.0, 1.0, 1.0)),
    ("state_prior_sigmas", (1.0, 1.0, 0.0, 1.0)), ("gate_probability", 1.0),
    ("gate_probability", 0.0), ("gate_probability", True),
])
def test_a_bad_value_names_its_field(field, value):
    with pytest.raises(ValidationError, match=field):
        JointOptions(**{field: value})


def test_association_options_check_their_fields():
    assert AssociationOptions().noise is None
    o = AssociationOptions(noise=MeasurementNoise(), pose_inflation=0, link_gate_m=1)
    assert o.pose_inflation == 0.0 and type(o.link_gate_m) is float
    for field, value in (("gate_probability", 1.5), ("floor_m", 0.0), ("link_gate_m", -1.0),
                         ("velocity_error_mps", float("nan")), ("ambiguity_m", -0.1),
                         ("max_gap_s", 0.0), ("noise", (0.05, 0.1, 0.2))):
        with pytest.raises(ValidationError, match=field):
            AssociationOptions(**{field: value})
