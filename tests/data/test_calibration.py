"""The records of self-calibration (mmsnap_graph.data.calibration): a pairwise
estimate that is checked when it claims success, a network calibration with a
status and typed facts."""

from __future__ import annotations

import numpy as np
import pytest

from mmsnap_graph.data.calibration import PairwiseCalibration, RecordingCalibration
from mmsnap_graph.data.calibration_facts import (
    CalibrationStatus,
    JointFit,
    LagEvidence,
    PoseCovariance,
)
from mmsnap_graph.errors import ValidationError

COV = np.diag([1e-3, 2e-3, 1e-4])


def _cal(**kw) -> RecordingCalibration:
    base = dict(reference="S1", node_names=["S1", "S2"],
                poses={"S1": np.zeros(3), "S2": np.array([1.0, 2.0, 0.5])},
                covariances={"S1": np.zeros((3, 3)), "S2": COV}, lag_frames={"S1": 0, "S2": 0})
    return RecordingCalibration(**{**base, **kw})


def test_success_and_message_come_from_the_status():
    ok = _cal()
    assert ok.success and ok.status is CalibrationStatus.OK and ok.message == \
        CalibrationStatus.OK.message
    bad = _cal(status=CalibrationStatus.NOT_OBSERVABLE)
    assert not bad.success and bad.message == CalibrationStatus.NOT_OBSERVABLE.message
    assert _cal(status=2).status is CalibrationStatus.NOT_OBSERVABLE
    assert ok.node_names == ("S1", "S2")  # a list becomes a tuple


def test_facts_are_found_by_their_class():
    fit = JointFit(n_nodes=2, n_frames=100)
    first = PoseCovariance(method="marginals")
    second = PoseCovariance(method="long_run", bandwidth_frames=12, max_widening=3.0)
    cal = _cal(facts=[fit, first, second])
    assert cal.fact(JointFit) is fit and cal.fact(PoseCovariance) is first
    assert cal.facts_of(PoseCovariance) == (first, second)
    assert cal.fact(LagEvidence) is None and cal.facts_of(LagEvidence) == ()


@pytest.mark.parametrize("kw, match", [
    (dict(method="closed_form"), r"method='closed_form' must be one of"),
    (dict(facts=["lag not determined"]), r"facts must be CalibrationFact records"),
    (dict(edges=[{"node_a": "S1"}]), r"edges must be PairwiseCalibration records"),
    (dict(noise={"S1": 0.1}), r"noise must be a NoiseEstimate or None"),
])
def test_a_bad_record_field_is_named(kw, match):
    with pytest.raises(ValidationError, match=match):
        _cal(**kw)


def test_a_successful_pairwise_estimate_is_finite_and_positive_definite():
    e = PairwiseCalibration(node_a="S1", node_b="S2", pose=[1.0, 2.0, 0.1], covariance=COV)
    assert e.success and not e.has_points
    np.testing.assert_array_equal(e.covariance, COV)
    with pytest.raises(ValidationError, match="edge S1-S2 covariance must be positive definite"):
        PairwiseCalibration(node_a="S1", node_b="S2", pose=[1.0, 2.0, 0.1], covariance=-COV)
    with pytest.raises(ValidationError, match="edge S1-S2 pose must be finite"):
        PairwiseCalibration(node_a="S1", node_b="S2", pose=[np.nan, 2.0, 0.1], covariance=COV)
    # A failed closed form keeps its numbers as they came out (scipy's way).
    failed = PairwiseCalibration(pose=[np.nan] * 3, covariance=np.full((3, 3), np.inf),
                                 success=False, message="the covariance is not finite")
    assert (failed.node_a, failed.node_b) == ("a", "b") and np.isnan(failed.pose[0])
    with pytest.raises(ValidationError, match="lag_evidence must be a LagEvidence or None"):
        PairwiseCalibration(node_a="S1", node_b="S2", pose=[1.0, 2.0, 0.1], covariance=COV,
                            lag_evidence="lag 1 frames determined")


def test_matched_points_go_together_with_their_frames():
    pts = np.ones((4, 2))
    e = PairwiseCalibration(node_a="S1", node_b="S2", pose=[0, 0, 0], covariance=COV,
                            points_a_m=pts, points_b_m=pts, frames=np.arange(4))
    assert e.has_points and e.frames.dtype == np.int64
    with pytest.raises(ValidationError, match="points_a_m and points_b_m go together"):
        PairwiseCalibration(node_a="S1", node_b="S2", pose=[0, 0, 0], covariance=COV,
                            points_a_m=pts)
    with pytest.raises(ValidationError, match=r"frames must be \(4,\) integers"):
        PairwiseCalibration(node_a="S1", node_b="S2", pose=[0, 0, 0], covariance=COV,
                            points_a_m=pts, points_b_m=pts, frames=np.arange(3))
