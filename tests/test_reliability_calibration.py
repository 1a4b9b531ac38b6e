"""Issue 13, calibration side: ``joint_calibration`` raises only the
project's errors for bad options and returns ``success=False`` (never a
GTSAM or numpy error) when the estimation itself breaks down."""

from __future__ import annotations

import numpy as np
import pytest

from mmsnap_graph.calibration import JointOptions
from mmsnap_graph import MmsnapError
from mmsnap_graph.calibration import joint_calibration
from mmsnap_graph.calibration.joint.presolve import robust_cost
from mmsnap_graph.data.noise import MeasurementNoise
from mmsnap_graph.data.recording import Detections
from mmsnap_graph.errors import ValidationError
from mmsnap_graph.sim.scenes import COMMON_AREA_CENTERS, PAPER_CONFIGURATIONS, synthetic_scene

NOISE = MeasurementNoise(range_m=0.035, omega_rad=0.2, doppler_mps=0.18)


@pytest.fixture(scope="module")
def detections():
    scene = synthetic_scene(PAPER_CONFIGURATIONS["B"], center_m=COMMON_AREA_CENTERS["B"],
                            n_frames=80, noise=NOISE, rng=np.random.default_rng(5))
    return {n: Detections(frame=scene.frame, range_m=z[:, 0], omega_rad=z[:, 1],
                          doppler_mps=z[:, 2]) for n, z in scene.measurements.items()}


@pytest.mark.parametrize("option, value", [
    ("robust_k", 0.0), ("robust_k", -1.0), ("robust_k", float("nan")),
    ("robust_k", float("inf")),
    ("sigma_a_mps2", 0.0), ("sigma_a_mps2", float("nan")), ("sigma_a_mps2", -1.0),
    ("frame_period_s", 0.0), ("frame_period_s", float("nan")), ("frame_period_s", -0.15),
    ("max_iterations", 0), ("max_motion_gap_frames", 0),
])
def test_bad_options_raise_validation_errors_naming_them(detections, option, value):
    with pytest.raises(ValidationError, match=option):
        if option == "frame_period_s":
            joint_calibration(detections, JointOptions(motion=True), noise=NOISE,
                              frame_period_s=value)
        else:
            joint_calibration(detections, JointOptions(motion=True, **{option: value}),
                              noise=NOISE, frame_period_s=0.15)


@pytest.mark.parametrize("sigma", [1e-300, 1e-160])
def test_vanishing_sigmas_raise_a_validation_error_or_fail(detections, sigma):
    noise = MeasurementNoise(range_m=sigma, omega_rad=sigma, doppler_mps=sigma)
    try:
        result = joint_calibration(detections, noise=noise)
    except MmsnapError:
        return
    assert not result.success or np.all(np.isfinite(result.poses["S2"]))


def test_every_detection_an_outlier_gives_success_false(detections):
    # a threshold below every residual flags every detection
    result = joint_calibration(detections, JointOptions(gate_probability=1e-12), noise=NOISE)
    assert not result.success
    assert "outlier" in result.message


@pytest.mark.parametrize("robust", ["huber", "cauchy"])
def test_robust_cost_of_a_huge_kernel_width_is_the_gaussian_cost(robust):
    norm = np.array([0.5, 2.0, 1e3])
    cost = robust_cost(norm, robust, 1e200)  # was OverflowError (k**2 of a Python float)
    assert cost == pytest.approx(0.5 * np.sum(norm**2), rel=1e-9)


def test_robust_cost_of_huge_residuals_is_finite_or_inf_without_error():
    norm = np.array([1e200, 1e300])
    for robust in (None, "huber", "cauchy"):
        with np.errstate(over="ignore"):
            cost = robust_cost(norm, robust, 2.5)
        assert not np.isnan(cost)
