"""Sharp turns are not outliers (issue 12, item 5).

On clean data of a walker who turns instantly (straight legs between random
waypoints, :mod:`mmsnap_graph.sim.turns`), the constant-velocity motion
factors smooth the velocity across each turn and the joint calibration used
to flag the detections there as outliers: 73-87 of 1200 at its default
white acceleration (1 m/s^2), 9-14 at the recording calibration's (3 m/s^2),
on the three seeds below (before the per-frame refit of
``calibration.joint.graph.exonerate_turns``). The target: at most 0.5% flagged.
"""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from numpy.testing import assert_allclose

from mmsnap_graph.data.calibration_facts import JointFit
from mmsnap_graph.calibration import JointOptions
from factors.gtsam_factors import (
    constant_velocity_factor,
    measurement_noise,
    node_measurement_factor,
    pose_measurement_factor,
    state_prior_factor,
)
from mmsnap_graph.calibration import joint_calibration
from mmsnap_graph.calibration.joint.presolve import PresolveProblem, normal_equations
from mmsnap_graph.data.noise import MeasurementNoise
from mmsnap_graph.sim.clocks import timed_scene
from mmsnap_graph.sim.scenes import COMMON_AREA_CENTERS, PAPER_CONFIGURATIONS
from mmsnap_graph.sim.turns import turning_walk, turning_walk_states

NOISE = MeasurementNoise(range_m=0.035, omega_rad=0.2, doppler_mps=0.18)
T = 0.15


def _scene(seed, n_frames=600, ghost_fraction=0.0):
    rng = np.random.default_rng(seed)
    scene = timed_scene(PAPER_CONFIGURATIONS["B"], time_offsets_s={}, n_frames=n_frames,
                        kind="turns", center_m=COMMON_AREA_CENTERS["B"], extent_m=1.0,
                        noise=NOISE, rng=rng)
    ghost = {}
    for n, z in scene.measurements.items():
        g = rng.random(n_frames) < ghost_fraction
        z[g, 0] = rng.uniform(1.0, 10.0, g.sum())
        z[g, 1] = rng.uniform(-np.pi / 2, np.pi / 2, g.sum())
        z[g, 2] = rng.uniform(-2.0, 2.0, g.sum())
        ghost[n] = g
    return scene, ghost


def test_the_walk_turns_instantly():
    walk = turning_walk([2.0, 3.0], duration_s=60.0, speed_mps=1.2, rng=np.random.default_rng(0))
    s = walk(np.arange(0.0, 60.0, 0.01))
    assert_allclose(np.linalg.norm(s[:, 2:], axis=1), 1.2)
    dv = np.linalg.norm(np.diff(s[:, 2:], axis=0), axis=1)
    assert np.sum(dv > 0.5) >= 20  # many velocity jumps of more than 0.5 m/s in 10 ms
    assert np.all(np.abs(s[:, :2] - [2.0, 3.0]) <= 1.5 + 1e-9)
    states = turning_walk_states([2.0, 3.0], n_frames=50, rng=np.random.default_rng(0))
    assert states.shape == (50, 4)


@pytest.mark.parametrize("sigma_a", [1.0, 3.0])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_clean_turning_walk_flags_at_most_half_a_percent(seed, sigma_a):
    """Failed before (73-87 and 9-14 of 1200 flagged); measured now 0-1."""
    scene, _ = _scene(seed)
    dets = {n: (scene.frame, z) for n, z in scene.measurements.items()}
    res = joint_calibration(dets, JointOptions(motion=True, sigma_a_mps2=sigma_a), noise=NOISE,
                            frame_period_s=T)
    flagged = sum(int(o.sum()) for o in res.outliers.values())
    assert flagged <= 0.005 * 2 * scene.frame.size, (flagged, res.facts)
    assert res.success and res.turns > 0, res.facts


def test_ghosts_in_a_turning_walk_are_still_flagged():
    """10% ghosts per node: at least 90% flagged, at most 0.5% of the good
    detections."""
    scene, ghost = _scene(3, ghost_fraction=0.1)
    dets = {n: (scene.frame, z) for n, z in scene.measurements.items()}
    res = joint_calibration(dets, JointOptions(motion=True, sigma_a_mps2=3.0), noise=NOISE,
                            frame_period_s=T)
    g = np.concatenate([ghost["S1"], ghost["S2"]])
    got = np.concatenate([res.outliers["S1"], res.outliers["S2"]])
    assert np.mean(got[g]) > 0.9 and np.mean(got[~g]) <= 0.005


@pytest.mark.parametrize("kernel", ["huber", "cauchy"])
def test_presolve_with_a_motion_kernel_matches_gtsam(kernel):
    """``motion_robust``: the pre-solve's IRLS-weighted motion factors equal
    GTSAM's robust constant-velocity factors (Hessian and gradient)."""
    rng = np.random.default_rng(12)
    scene, _ = _scene(4, n_frames=6)
    sig = NOISE.sigmas
    meas = scene.measurements
    poses = {"S1": np.zeros(3), "S2": scene.poses["S2"] + [0.1, -0.05, 0.03]}
    states = scene.truth + rng.normal(size=scene.truth.shape) * 0.2
    prior = np.array([1e3, 1e3, 3.5, 3.5])
    motion = (np.arange(5), np.full(5, T), 0.7, kernel, 3.0)
    problem = PresolveProblem(measurements=meas, names=["S1", "S2"], reference="S1", sigmas=sig,
                              prior_sigmas=prior, motion=motion)
    hmat, g = normal_equations(problem, poses, states)
    graph, values, order = gtsam.NonlinearFactorGraph(), gtsam.Values(), gtsam.Ordering()
    x = gtsam.symbol("x", 1)
    values.insert(x, gtsam.Pose2(*poses["S2"]))
    noise = measurement_noise(sig)
    for i in range(6):
        v = gtsam.symbol("v", i)
        values.insert(v, states[i])
        order.push_back(v)
        graph.add(node_measurement_factor(v, np.zeros(3), meas["S1"][i], noise))
        graph.add(pose_measurement_factor(x, v, meas["S2"][i], noise))
        graph.add(state_prior_factor(v, np.zeros(4), prior))
        if i < 5:
            graph.add(constant_velocity_factor(v, gtsam.symbol("v", i + 1), T, 0.7, kernel, 3.0))
    order.push_back(x)
    h_ref, eta = graph.linearize(values).hessian(order)
    assert_allclose(hmat.toarray(), h_ref, atol=1e-9 * np.abs(h_ref).max())
    assert_allclose(g, -eta.ravel(), atol=1e-9 * np.abs(eta).max())


def test_motion_kernel_option_runs_and_keeps_turns_clean():
    """The optional kernel on the motion factors (an alternative to the
    refit; it costs ghost robustness, docs/CALIBRATION.md) leaves the clean
    turning walk with few flags too and reports the turns it left out."""
    scene, _ = _scene(0)
    dets = {n: (scene.frame, z) for n, z in scene.measurements.items()}
    options = JointOptions(motion=True, sigma_a_mps2=1.0, motion_robust="cauchy")
    res = joint_calibration(dets, options, noise=NOISE, frame_period_s=T)
    assert sum(int(o.sum()) for o in res.outliers.values()) <= 6
    (fit,) = [f for f in res.facts if isinstance(f, JointFit)]
    assert res.turns > 0 and fit.turns == res.turns
