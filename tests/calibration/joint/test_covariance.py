"""The joint graph's pose covariance when errors are correlated in time
(``calibration.joint.covariance`` and ``presolve.pose_influences``).

Measured (3-node network of tests/calibration/test_network.py, one random
walker, 300 frames at 150 ms, the real physics without clutter, ghosts,
split clusters or reflection depth, so that only the AR(1) centroid errors
(0.045 m, 0.7 s, and the fast part's 0.04 s) break the model; joint NEES of
the two poses, chi-square(6), seeds 0-19, band of the mean 4.58-7.61): the
graph's marginals 12.87; the long-run covariance (2 s Bartlett bandwidth)
widened per direction beyond two standard errors 8.86, although at the mean
reported covariance the NEES was 6.62 (bias part 0.11): each recording's
covariance is estimated from its own 300 frames (about 32 degrees of
freedom), and the inverse of a noisy covariance is too large on the
average. A 6 s bandwidth gave 9.49, no threshold 8.28, AR(1)-prewhitened
influences 8.82. Now (the whole block's test, then the long-run estimate
times ``nu / (nu - P - 1)``): 6.64; the clean model's network NEES on the
same 300-frame scenes, seeds 0-29, 5.40 -> 5.84 (band 4.80-7.37).
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np
import pytest
from scipy.stats import chi2

from mmsnap_graph.calibration import calibrate_recording, joint_calibration, pose_tangent_error
from mmsnap_graph.calibration.joint.covariance import (
    bandwidth_frames,
    block_covariance,
    depth_data_sigma,
    long_run_covariance,
    NODE_DEPTH_SHARE,
    range_offset_response,
    robust_covariance,
)
from mmsnap_graph.calibration.joint.options import REFLECTION_DEPTH_RMS_M, JointOptions
from mmsnap_graph.calibration.joint.presolve import (
    RANGE_OFFSET,
    PresolveProblem,
    normal_equations,
    pose_influences,
    presolve,
)
from mmsnap_graph.calibration.network import POINT_JOINT_OPTIONS
from mmsnap_graph.data.calibration_facts import JointFit, PoseCovariance
from mmsnap_graph.data.noise import MeasurementNoise
from mmsnap_graph.errors import ValidationError
from mmsnap_graph.sim import simulate_recording
from mmsnap_graph.sim.options import SimulationOptions
from mmsnap_graph.sim import RealPhysics
from _scenes import depth_scene

NET = {"S1": [0.0, 0.0, 0.0], "S2": [5.0, 5.0, np.pi / 2], "S3": [0.0, 7.0, np.pi]}
SIGMAS = np.array([0.03, 0.05, 0.1])
#: The real physics with only the centroid errors' correlation in time left
#: (no clutter, ghosts, split clusters, false alarms or reflection depth).
CORRELATED_ONLY = RealPhysics(static_centroids_per_frame=0, ghost_probability=0,
                              split_probability=0, false_alarm_fraction=0.0,
                              reflection_depth_m=0.0, reflection_depth_std_m=0.0)


def _ar1(rng, n, rho, p=2):
    x = np.zeros((n, p))
    e = rng.normal(size=(n, p))
    for t in range(1, n):
        x[t] = rho * x[t - 1] + e[t]
    return x


def test_long_run_covariance_of_white_and_ar1_series():
    """Sums of T unit-variance draws: T for white noise; T (1 + rho) / (1 -
    rho) for AR(1) with a bandwidth well beyond its memory (Bartlett's bias
    ~ 1 / bandwidth)."""
    rng = np.random.default_rng(0)
    n = 40000
    white = rng.normal(size=(n, 2))
    lr = long_run_covariance(white, np.arange(n), 20)
    np.testing.assert_allclose(np.diag(lr) / n, 1.0, rtol=0.1)  # sd 2.6%
    rho = 0.8
    x = _ar1(rng, n, rho) * np.sqrt(1 - rho**2)  # unit variance
    lr = long_run_covariance(x, np.arange(n), 120)
    np.testing.assert_allclose(np.diag(lr) / n, (1 + rho) / (1 - rho), rtol=0.2)  # sd 6%, bias -7%
    gamma0 = np.diag(x.T @ x) / n
    assert np.all(np.diag(lr) / n > 5 * gamma0)
    with pytest.raises(ValidationError, match="strictly increasing"):
        long_run_covariance(white[:3], np.array([0, 2, 2]), 1)
    with pytest.raises(ValidationError, match="bandwidth"):
        long_run_covariance(white[:3], np.arange(3), -1)
    assert bandwidth_frames(2.0, 0.05) == 40 and bandwidth_frames(2.0, 0.15) == 14
    assert bandwidth_frames(2.0, None) == 1


def test_robust_covariance_keeps_the_model_within_its_noise_and_widens_beyond():
    model = np.diag([4.0, 1.0, 0.25])
    same, f = robust_covariance(model, 1.05 * model, n_frames=300, bandwidth=13)
    np.testing.assert_allclose(same, model)
    assert np.all(f == 1.0)
    # One direction 1.5x: beyond one Bartlett estimate's two standard errors
    # (1.48x) but the block's mean (1.17x) within its noise (1.28x): kept.
    one = model.copy()
    one[0, 0] *= 1.5
    kept, f = robust_covariance(model, one, n_frames=300, bandwidth=13)
    np.testing.assert_allclose(kept, model)
    wide = model.copy()
    wide[0, 0] *= 9.0  # the first direction's errors last: 9x the variance
    out, f = robust_covariance(model, wide, n_frames=300, bandwidth=13)
    nu = 3 * 300 / (2 * 13)
    c = nu / (nu - 3 - 1)  # the small-sample factor of nu degrees of freedom
    np.testing.assert_allclose(np.diag(out), [36.0 * c, c, 0.25 * c], rtol=1e-9)
    assert f[0] == pytest.approx(9.0 * c) and np.allclose(f[1:], c)
    assert np.all(np.linalg.eigvalsh(out - model) > -1e-12)


def _scene(seed=0, n=60, depth=0.07):
    """Three nodes seeing a target on a smooth walk; every range ``depth``
    short (a reflection depth)."""
    return depth_scene(SIGMAS, seed, n, depth)


@pytest.mark.parametrize("timed", [False, True])
def test_influences_sum_to_zero_and_the_model_is_the_inverse_hessian(timed):
    poses, states, meas = _scene()
    motion = (np.arange(59), np.full(59, 0.15), 2.0)
    problem = PresolveProblem(measurements=meas, names=list(poses), reference="S1",
                              sigmas=SIGMAS, prior_sigmas=np.array([1e3, 1e3, 3.5, 3.5]),
                              motion=motion, range_offset=(0.1, 0.05))
    start = {RANGE_OFFSET: 0.1, **({"S2": 0.0, "S3": 0.0} if timed else {})}
    p, s, o = presolve(problem, poses, states, offsets=start, tol=1e-14, max_steps=200)
    infl, cov = pose_influences(problem, p, s, offsets=o)
    assert infl.shape == (60, 6 + 2 * timed + 1)
    assert np.max(np.abs(infl.sum(0))) < 1e-3 * np.sqrt(np.max(np.diag(cov)))  # to the solve's tolerance
    hess, _ = normal_equations(problem, p, s, offsets=o)
    dense = np.linalg.inv(hess.toarray())[240:, 240:]
    np.testing.assert_allclose(cov, dense, rtol=1e-8, atol=1e-14)
    with pytest.raises(ValidationError, match="Gaussian"):
        pose_influences(dataclasses.replace(problem, robust="cauchy"), p, s, offsets=o)


def test_range_offset_response_is_the_poses_move_when_every_range_lengthens():
    """The considered reflection depth's direction: the poses' response to
    every range lengthened by 0.02 m (solved again) is ``0.02 J`` to the
    solve's linearisation; the long-run covariance adds ``s^2 J J^T``, and
    nothing when the graph estimates the offset itself."""
    poses, states, meas = _scene()
    motion = (np.arange(59), np.full(59, 0.15), 2.0)
    problem = PresolveProblem(measurements=meas, names=list(poses), reference="S1",
                              sigmas=SIGMAS, prior_sigmas=np.array([1e3, 1e3, 3.5, 3.5]),
                              motion=motion)
    p, s = presolve(problem, poses, states, tol=1e-14, max_steps=200)
    j = range_offset_response(problem, p, s, None)
    longer = {n: m + np.array([0.02, 0.0, 0.0]) for n, m in meas.items()}
    p2, _ = presolve(dataclasses.replace(problem, measurements=longer), p, s, tol=1e-14,
                        max_steps=200)
    moved = np.concatenate([pose_tangent_error(p2[n], p[n]) for n in ("S2", "S3")])
    np.testing.assert_allclose(moved, 0.02 * j, rtol=0.02, atol=1e-5)
    assert np.linalg.norm(j[:2]) > 0.5  # a range offset moves the poses (about 1 m per m)
    frames = np.arange(60)
    plain = block_covariance(problem, p, s, None, frames, bandwidth=3, timed=())
    depth = block_covariance(problem, p, s, None, frames, bandwidth=3, timed=(),
                             range_offset_rms=0.1)
    own = {n: range_offset_response(problem, p, s, None, node=n) for n in poses}
    np.testing.assert_allclose(sum(own.values()), j, rtol=1e-6, atol=1e-9)  # linear in the ranges
    assert np.linalg.norm(own["S2"] - j) > 0.1      # the nodes' own depths move the poses apart
    q = NODE_DEPTH_SHARE
    want = 0.01 * ((1 - q) * np.outer(j, j) + q * sum(np.outer(v, v) for v in own.values()))
    np.testing.assert_allclose(depth.covariance - plain.covariance, want, rtol=1e-9, atol=1e-15)
    assert depth.fact().reflection_depth_rms_m == 0.1
    # the fact says each node's sigmas without the depth: the plain covariance's
    np.testing.assert_allclose(depth.random, plain.covariance, rtol=0, atol=0)
    fact = depth.fact()
    assert fact.without_depth_nodes == ("S2", "S3")
    np.testing.assert_allclose(np.reshape(fact.without_depth_sigmas, (2, 3)),
                               [np.sqrt(np.diag(plain.node(n))) for n in ("S2", "S3")])
    assert plain.fact().without_depth_nodes == ()
    estimated = dataclasses.replace(problem, range_offset=(0.1, 0.05))
    p3, s3, o3 = presolve(estimated, poses, states, offsets={RANGE_OFFSET: 0.1}, tol=1e-14,
                          max_steps=200)
    kept = block_covariance(estimated, p3, s3, o3, frames, bandwidth=3, timed=(),
                            range_offset_rms=0.1)
    assert kept.range_offset_rms == 0.0 and kept.fact().reflection_depth_rms_m == 0.0


def _facing_problem(seed=0, n=120):
    """Two nodes 8 m apart facing each other, a target walking between them
    (0.8 m either side of the line, 2-6 m from S1), ranges 0.07 m short."""
    from factors.models import measurement_model
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.15
    states = np.column_stack([0.8 * np.sin(0.7 * t), 4.0 + 2.0 * np.sin(0.25 * t),
                              0.56 * np.cos(0.7 * t), 0.5 * np.cos(0.25 * t)])
    poses = {"S1": np.zeros(3), "S2": np.array([0.0, 8.0, np.pi])}
    meas = {}
    for name, pose in poses.items():
        h, _ = measurement_model(states, pose)
        h[:, 0] -= 0.07
        meas[name] = h + rng.normal(0.0, SIGMAS, (n, 3))
    return poses, states, meas


def _plain_problem(meas, names):
    return PresolveProblem(measurements=meas, names=list(names), reference="S1", sigmas=SIGMAS,
                           prior_sigmas=np.array([1e3, 1e3, 3.5, 3.5]),
                           motion=(np.arange(len(meas["S1"]) - 1),
                                   np.full(len(meas["S1"]) - 1, 0.15), 2.0))


def test_depth_data_sigma_says_where_the_geometry_separates_the_depth_from_the_poses():
    """The depth's sigma from the data alone is the range offset's sigma of
    the graph that estimates it with a flat prior, at the same point (the
    model's; the long-run one is never below it). Three nodes around the
    walk fix it to about 2 cm (below half the considered rms);
    two facing nodes with the walker between them to 4 times that
    (a shorter baseline looks the same on the line between them), and
    block_covariance's fact carries the figure."""
    rows = {}
    for name, (poses, states, meas) in (("around", _scene(n=120)), ("facing", _facing_problem())):
        problem = _plain_problem(meas, poses)
        p, s = presolve(problem, poses, states, tol=1e-14, max_steps=200)
        frames = np.arange(len(meas["S1"]))
        alone = depth_data_sigma(problem, p, s, None, frames, bandwidth=None)
        flat = dataclasses.replace(problem, range_offset=(0.0, 1e3))
        _, cov = pose_influences(flat, p, s, offsets={RANGE_OFFSET: 0.0})
        assert alone == pytest.approx(np.sqrt(cov[-1, -1]), rel=1e-9)
        assert depth_data_sigma(problem, p, s, None, frames, bandwidth=5) >= alone * (1 - 1e-9)
        block = block_covariance(problem, p, s, None, frames, bandwidth=5, timed=(),
                                 range_offset_rms=REFLECTION_DEPTH_RMS_M)
        assert block.fact().depth_data_sigma_m == block.depth_data_sigma_m > 0
        rows[name] = block.depth_data_sigma_m
        with pytest.raises(ValidationError, match="already estimates"):
            depth_data_sigma(flat, p, s, None, frames, bandwidth=None)
    limit = 0.5 * REFLECTION_DEPTH_RMS_M
    assert rows["around"] < 0.5 * limit < limit < rows["facing"], rows  # 0.018 m, 0.072 m
    assert rows["facing"] > 3.0 * rows["around"]


def _sim(seed, physics):
    return simulate_recording(NET, "random", SimulationOptions(physics=physics),
                              levels=("centroids",), n_frames=300, seed=seed)


def test_reported_marginals_and_facts():
    """``covariance="model"`` reports the graph's marginals, equal to the
    long-run result's ``model_covariances``; the long-run covariance is
    never below them; the facts say how the solve converged and how the
    covariance was computed."""
    phys = CORRELATED_ONLY
    rec = _sim(0, phys)
    model = calibrate_recording(rec, joint=dataclasses.replace(POINT_JOINT_OPTIONS,
                                                               covariance="model"))
    long_run = calibrate_recording(rec)
    for n in ("S2", "S3"):
        np.testing.assert_allclose(model.covariances[n], model.model_covariances[n])
        np.testing.assert_allclose(long_run.model_covariances[n], model.covariances[n],
                                   rtol=1e-4, atol=1e-12)  # numpy Schur vs GTSAM
        assert np.all(np.linalg.eigvalsh(long_run.covariances[n] - model.covariances[n])
                      > -1e-12)
    fit = long_run.fact(JointFit)
    assert fit.presolve_steps and fit.presolve_converged and fit.iterations >= 1
    assert long_run.fact(PoseCovariance).method == "long_run"
    assert model.fact(PoseCovariance).method == "marginals"


@functools.lru_cache(maxsize=1)
def _correlated_nees() -> dict[str, float]:
    """Mean joint NEES of the marginals and of the long-run covariance,
    seeds 0-19 (module doc)."""
    nees = {"model": [], "long_run": []}
    for seed in range(20):
        rec = _sim(seed, CORRELATED_ONLY)
        for kind in nees:
            cal = calibrate_recording(rec, joint=dataclasses.replace(POINT_JOINT_OPTIONS,
                                                                     covariance=kind))
            e = np.concatenate([pose_tangent_error(cal.poses[n], rec.truth.node_poses[n])
                                for n in cal.joint_order])
            nees[kind].append(float(e @ np.linalg.solve(cal.joint_covariance, e)))
    return {k: float(np.mean(v)) for k, v in nees.items()}


BAND = tuple(chi2.ppf([0.025, 0.975], 6 * 20) / 20)


@pytest.mark.slow
def test_correlated_errors_long_run_covariance_lowers_the_nees():
    """Module doc: the marginals' NEES is above the band; the long-run
    covariance takes at least a quarter of it off (12.9 -> 6.6 measured)."""
    means = _correlated_nees()
    assert means["model"] > BAND[1]
    assert means["long_run"] < 0.75 * means["model"]


@pytest.mark.slow
def test_correlated_errors_long_run_nees_in_band():
    """Module doc: 6.64 (was 8.86 with the per-direction widening)."""
    means = _correlated_nees()
    assert BAND[0] < means["long_run"] < BAND[1]


def test_joint_options_check_the_new_fields():
    with pytest.raises(ValidationError, match="covariance="):
        JointOptions(covariance="sandwich")
    with pytest.raises(ValidationError, match="covariance_bandwidth_s"):
        JointOptions(covariance_bandwidth_s=0.0)
    with pytest.raises(ValidationError, match="range_offset_prior_m"):
        JointOptions(range_offset_prior_m=(0.1,))
    with pytest.raises(ValidationError, match="range_offset_prior_m sigma"):
        JointOptions(range_offset_prior_m=(0.1, 0.0))
    with pytest.raises(ValidationError, match="within"):
        JointOptions(range_offset_prior_m=(10.0, 0.05))
    assert JointOptions(range_offset_prior_m=[0.1, 0.05]).range_offset_prior_m == (0.1, 0.05)
    with pytest.raises(ValidationError, match="range_offset_rms_m must be > 0"):
        JointOptions(range_offset_rms_m=0.0)
    with pytest.raises(ValidationError, match="centimetres"):
        JointOptions(range_offset_rms_m=11.2)
    assert POINT_JOINT_OPTIONS.range_offset_rms_m is None  # a point target: not considered
    assert REFLECTION_DEPTH_RMS_M == pytest.approx(0.1118, abs=1e-4)


def test_joint_calibration_without_a_frame_period_keeps_the_marginals():
    poses, states, meas = _scene(1, depth=0.0)
    frames = np.arange(60)
    dets = {n: (frames, m) for n, m in meas.items()}
    noise = MeasurementNoise(range_m=0.03, omega_rad=0.05, doppler_mps=0.1)
    res = joint_calibration(dets, noise=noise, initial_poses=poses)
    assert res.success, res.facts
    for n in ("S2", "S3"):
        np.testing.assert_allclose(res.covariances[n], res.model_covariances[n])
