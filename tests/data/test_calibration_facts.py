"""A calibration's status and typed facts (mmsnap_graph.data.calibration_facts):
one status table, constructors that coerce JSON values to the declared types
and name the field of a bad one."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from mmsnap_graph.data.calibration_facts import (
    FACT_KINDS,
    FACTS,
    NOISE_COMPONENTS,
    CalibrationFact,
    CalibrationStatus,
    ClockOffsetsTried,
    JointNoise,
    LagEvidence,
    LagNotDetermined,
    NoiseNotIdentified,
    PoseCovariance,
    PoseNotObservable,
)
from mmsnap_graph.errors import ValidationError


def test_every_status_has_one_message_and_a_label_that_reads_back():
    messages = [s.message for s in CalibrationStatus]
    assert len(set(messages)) == len(messages) and all(messages)
    assert CalibrationStatus.OK == 0
    for s in CalibrationStatus:
        assert CalibrationStatus.from_name(s.label) is s
        assert CalibrationStatus.from_name(s.name) is s
    with pytest.raises(ValidationError, match=r"status 'fine' must be one of \['ok', "):
        CalibrationStatus.from_name("fine")


def test_every_fact_kind_is_named_once_and_is_a_frozen_record():
    assert len(FACT_KINDS) == len(FACTS)
    for cls in FACTS:
        assert issubclass(cls, CalibrationFact) and FACT_KINDS[cls.kind] is cls
        assert dataclasses.is_dataclass(cls) and cls.__dataclass_params__.frozen


def test_json_values_are_coerced_to_the_declared_types():
    """Lists become tuples, None a NaN float, a status name the enum, numpy
    values plain Python ones: what a JSON reader hands over is the record."""
    f = LagNotDetermined(node_a="S1", node_b="S2", tested=True, kept_shifts=[1],
                         rejected_shifts=np.array([-1, 2]), clock_fraction=None,
                         clock_sigma=np.float64(0.25))
    assert f.kept_shifts == (1,) and f.rejected_shifts == (-1, 2)
    assert type(f.rejected_shifts[0]) is int and math.isnan(f.clock_fraction)
    assert type(f.clock_sigma) is float
    noise = JointNoise(sigmas=np.array([0.05, 0.08, 0.1]), identified=np.array([True, False, True]),
                       source="temporal")
    assert noise.identified == (True, False, True) and type(noise.identified[0]) is bool
    tried = ClockOffsetsTried(outcome="solve_failed", solve_status="not_observable")
    assert tried.solve_status is CalibrationStatus.NOT_OBSERVABLE
    assert ClockOffsetsTried(outcome="no_start", solve_status=3).solve_status \
        is CalibrationStatus.SOLVE_FAILED
    dirs = PoseNotObservable(node="S2", directions=[[1, 0, 0]])
    assert dirs.directions == ((1.0, 0.0, 0.0),)
    assert LagEvidence(lag_frames=2.0, outcome="determined").lag_frames == 2


@pytest.mark.parametrize("make, match", [
    (lambda: PoseCovariance(method="guess"),
     r"pose_covariance.method='guess' must be one of \['marginals', 'long_run', 'schur'\]"),
    (lambda: LagEvidence(lag_frames=1.5, outcome="determined"),
     r"lag_evidence.lag_frames must be an integer, got 1.5"),
    (lambda: LagEvidence(lag_frames=True, outcome="determined"),
     r"lag_evidence.lag_frames must be a number, got True"),
    (lambda: JointNoise(sigmas=(0.1, 0.2), identified=(True,) * 3, source="temporal"),
     r"joint_noise.sigmas must hold 3 values"),
    (lambda: JointNoise(sigmas=(0.1, "x", 0.3), identified=(True,) * 3, source="temporal"),
     r"joint_noise.sigmas\[1\] must be a number, got 'x'"),
    (lambda: LagNotDetermined(node_a="S1", node_b="S2", tested="yes"),
     r"lag_not_determined.tested must be true or false"),
    (lambda: LagNotDetermined(node_a=1, node_b="S2", tested=True),
     r"lag_not_determined.node_a must be a string, got 1"),
    (lambda: NoiseNotIdentified(node="S1", component="angle", sigma=0.1),
     r"noise_not_identified.component='angle' must be one of"),
    (lambda: ClockOffsetsTried(outcome="no_start", solve_status="late"),
     r"status 'late' must be one of"),
    (lambda: PoseNotObservable(node="S2", directions=[1, 0, 0]),
     r"pose_not_observable.directions\[0\] must be a sequence"),
])
def test_a_bad_field_is_a_validation_error_naming_it(make, match):
    with pytest.raises(ValidationError, match=match):
        make()


def test_the_noise_components_are_in_the_sigmas_order():
    assert NOISE_COMPONENTS == ("range", "omega", "doppler")


def test_lag_evidence_says_which_lag_the_matching_kept():
    kept = {o: LagEvidence(lag_frames=3, outcome=o).kept_lag_frames
            for o in ("determined", "untested", "not_determined", "window_edge")}
    assert kept == {"determined": 3, "untested": 3, "not_determined": 0, "window_edge": 0}


def test_an_integer_beyond_the_float_range_is_infinite_not_an_overflow():
    f = LagNotDetermined(node_a="S1", node_b="S2", tested=True, clock_fraction=10 ** 400)
    assert f.clock_fraction == math.inf
    assert LagEvidence(lag_frames=10 ** 30, outcome="determined").lag_frames == 10 ** 30
    with pytest.raises(ValidationError, match="lag_evidence.lag_frames must be an integer"):
        LagEvidence(lag_frames=math.inf, outcome="determined")
