"""The numpy presolve of the joint calibration graph
(mmsnap_graph.calibration.joint.presolve): its kernels, costs and linear
system against GTSAM's own."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from numpy.testing import assert_allclose

from factors.gtsam_factors import constant_velocity_factor
from mmsnap_graph.calibration.joint.presolve import (
    PresolveProblem,
    cv_information,
    kernel_weight,
    normal_equations,
    robust_cost,
)
from mmsnap_graph.data.noise import MeasurementNoise
from mmsnap_graph.sim.scenes import COMMON_AREA_CENTERS, PAPER_CONFIGURATIONS, synthetic_scene

MODERATE_NOISE = MeasurementNoise(range_m=0.035, omega_rad=0.2, doppler_mps=0.18)


def _scene(config, rng, **kw):
    return synthetic_scene(PAPER_CONFIGURATIONS[config], center_m=COMMON_AREA_CENTERS[config],
                           rng=rng, **kw)


def _gtsam_estimator(robust, k):
    est = gtsam.noiseModel.mEstimator
    return {"huber": est.Huber, "cauchy": est.Cauchy}[robust].Create(k)


@pytest.mark.parametrize("robust, k", [("huber", 1.345), ("huber", 0.5), ("cauchy", 2.5),
                                       ("cauchy", 0.3)])
def test_robust_cost_and_weight_are_gtsams_m_estimator(robust, k):
    """Per residual norm (inside and beyond the kernel width), the cost is
    GTSAM's mEstimator loss and the IRLS weight its weight (rel 1e-12)."""
    norms = np.array([0.0, 0.1, 0.9 * k, k, 1.1 * k, 3.0, 40.0])
    ref = _gtsam_estimator(robust, k)
    for e in norms:
        assert robust_cost(np.array([e]), robust, k) == pytest.approx(ref.loss(e), rel=1e-12,
                                                                       abs=1e-300)
        assert kernel_weight(np.array([e]), robust, k)[0] == pytest.approx(ref.weight(e),
                                                                           rel=1e-12)
    # the cost of several residuals is the sum of theirs
    assert robust_cost(norms, robust, k) == pytest.approx(sum(ref.loss(e) for e in norms),
                                                          rel=1e-12)


def test_without_a_kernel_the_cost_is_half_the_squares_and_the_weight_one():
    norms = np.array([0.0, 0.5, 2.0, 30.0])
    assert robust_cost(norms, None, 1.0) == pytest.approx(0.5 * np.sum(norms**2), rel=1e-15)
    assert_allclose(kernel_weight(norms, None, 1.0), 1.0)


def test_cv_information_matches_the_gtsam_factor():
    factor = constant_velocity_factor(1, 2, 0.3, 0.7)
    r = factor.noiseModel().R()
    assert_allclose(cv_information(0.3, 0.7), r.T @ r, rtol=1e-9)


@pytest.mark.parametrize("robust", [None, "huber", "cauchy"])
def test_presolve_linear_system_matches_gtsam_linearization(robust):
    """The numpy presolve's Hessian and gradient equal GTSAM's linearization
    of the same graph (measurement, prior and constant-velocity factors), at
    a point away from the optimum. With a kernel, GTSAM reweights each
    factor (IRLS), as the presolve does."""
    from factors.gtsam_factors import (
        measurement_noise,
        node_measurement_factor,
        pose_measurement_factor,
        state_prior_factor,
    )
    sig = MODERATE_NOISE.sigmas
    rng = np.random.default_rng(12)
    scene = _scene("C", rng, n_frames=6, noise=MODERATE_NOISE)
    meas = {n: scene.measurements[n] for n in ("S1", "S2")}
    poses = {"S1": np.zeros(3), "S2": scene.poses["S2"] + [0.1, -0.05, 0.03]}
    states = scene.truth + rng.normal(size=scene.truth.shape) * 0.2
    prior = np.array([1e3, 1e3, 3.5, 3.5])
    k = {None: 1.0, "huber": 1.345, "cauchy": 2.5}[robust]
    motion = (np.arange(5), np.full(5, 0.15), 0.7)
    problem = PresolveProblem(measurements=meas, names=["S1", "S2"], reference="S1", sigmas=sig,
                              prior_sigmas=prior, robust=robust, k=k, motion=motion)
    hmat, g = normal_equations(problem, poses, states)
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    x = gtsam.symbol("x", 1)
    values.insert(x, gtsam.Pose2(*poses["S2"]))
    noise = measurement_noise(sig, robust, None if robust is None else k)
    for i in range(6):
        v = gtsam.symbol("v", i)
        values.insert(v, states[i])
        graph.add(node_measurement_factor(v, np.zeros(3), meas["S1"][i], noise))
        graph.add(pose_measurement_factor(x, v, meas["S2"][i], noise))
        graph.add(state_prior_factor(v, np.zeros(4), prior))
        if i < 5:
            graph.add(constant_velocity_factor(v, gtsam.symbol("v", i + 1), 0.15, 0.7))
    order = gtsam.Ordering()
    for i in range(6):
        order.push_back(gtsam.symbol("v", i))
    order.push_back(x)
    h_ref, eta = graph.linearize(values).hessian(order)
    scale = np.abs(h_ref).max()
    assert_allclose(hmat.toarray(), h_ref, atol=1e-9 * scale)
    assert_allclose(g, -eta.ravel(), atol=1e-9 * np.abs(eta).max())


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


# The range offset unknown (PresolveProblem.range_offset): gradient, Hessian, recovery.

from mmsnap_graph.calibration.joint.presolve import RANGE_OFFSET, _problem, presolve  # noqa: E402
from _scenes import depth_scene  # noqa: E402

RO_SIGMAS = np.array([0.03, 0.05, 0.1])


def _offset_scene(seed=0, n=60, depth=0.07):
    return depth_scene(RO_SIGMAS, seed, n, depth)


def _ro_problem(meas, names, prior=(0.1, 0.05)):
    return PresolveProblem(measurements=meas, names=names, reference="S1", sigmas=RO_SIGMAS,
                           prior_sigmas=np.array([1e3, 1e3, 3.5, 3.5]),
                           motion=(np.arange(59), np.full(59, 0.15), 2.0), range_offset=prior)


@pytest.mark.parametrize("timed", [False, True])
def test_range_offset_gradient_and_hessian_match_finite_differences(timed):
    poses, states, meas = _offset_scene()
    offsets = {RANGE_OFFSET: 0.06, **({"S2": 0.01, "S3": -0.02} if timed else {})}
    prob, p, s, o = _problem(_ro_problem(meas, list(poses)), poses, states, offsets)
    hess, grad = prob.system(p, s, o)
    col = prob.s0 + prob.dcol
    eps = 1e-6
    up, down = {**o, RANGE_OFFSET: o[RANGE_OFFSET] + eps}, {**o, RANGE_OFFSET: o[RANGE_OFFSET] - eps}
    numeric = (prob.cost(p, s, up) - prob.cost(p, s, down)) / (2 * eps)
    assert grad[col] == pytest.approx(numeric, rel=1e-6)
    numeric_col = (prob.system(p, s, up)[1] - prob.system(p, s, down)[1]) / (2 * eps)
    np.testing.assert_allclose(hess[:, col].toarray().ravel(), numeric_col,
                               atol=1e-6 * np.abs(numeric_col).max())


def test_presolve_recovers_the_range_offset():
    """True depth 0.07 m, prior 0.10 +- 0.05 m: within 2 sigma of the data."""
    poses, states, meas = _offset_scene()
    problem = _ro_problem(meas, list(poses))
    p, s, o = presolve(problem, poses, states, offsets={RANGE_OFFSET: 0.1})
    assert o == {RANGE_OFFSET: pytest.approx(o[RANGE_OFFSET])}  # not timed: the offset only
    assert abs(o[RANGE_OFFSET] - 0.07) < 0.02
    without = PresolveProblem(measurements=meas, names=list(poses), reference="S1",
                              sigmas=RO_SIGMAS, prior_sigmas=np.array([1e3, 1e3, 3.5, 3.5]),
                              motion=problem.motion)
    p0, _ = presolve(without, poses, states)
    # S3 faces S1 across 7.5 m: without the offset their baseline shrinks by ~2 d.
    assert np.linalg.norm(p0["S3"][:2]) < np.linalg.norm(poses["S3"][:2]) - 0.08
    assert abs(np.linalg.norm(p["S3"][:2]) - np.linalg.norm(poses["S3"][:2])) < 0.04
