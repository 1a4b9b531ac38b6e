"""Clock offsets (issue 12, item 1): the timed measurement factor's
Jacobians, the pre-solve's normal equations against GTSAM's, the simulator's
clock offsets, the offsets recovered by the joint calibration (the issue's
targets) and the fusion-side alignment of detections to the reference clock.

Convention: node time + offset = reference time; a node with offset ``tau``
took its frame ``k`` at reference time ``k T + tau``.
"""

from __future__ import annotations

import dataclasses
import functools
import json

import gtsam
import h5py
import numpy as np
import pytest
from gtsam.utils.numerical_derivative import (
    numericalDerivative31,
    numericalDerivative32,
    numericalDerivative33,
)
from numpy.testing import assert_allclose

from mmsnap_graph.calibration import JointOptions
from factors import models
from factors.gtsam_factors import (
    constant_velocity_factor,
    measurement_noise,
    node_measurement_factor,
    state_prior_factor,
    timed_pose_measurement_factor,
)
from mmsnap_graph.calibration import calibrate_recording, joint_calibration
from mmsnap_graph.data.calibration import RecordingCalibration
from mmsnap_graph.calibration.joint.presolve import PresolveProblem, normal_equations, shifted_states
from mmsnap_graph.data.noise import MeasurementNoise
from mmsnap_graph.data.recording import Detections
from mmsnap_graph.errors import CalibrationError, ValidationError
from mmsnap_graph.io import write_recording
from mmsnap_graph.io.calibration import (
    calibration_to_json,
    load_time_offsets,
    read_calibration,
    read_calibration_json,
    write_calibration,
    write_calibration_json,
)
from mmsnap_graph.fusion.recording.timing import align_detections, align_recording, split_offset
from mmsnap_graph.sim import simulate_recording
from mmsnap_graph.fusion.recording.sequence import fuse_recording
from mmsnap_graph.fusion.options import NetworkCalibration
from mmsnap_graph.sim.clocks import scene_recording, timed_scene, trajectory_function
from mmsnap_graph.sim.scenes import COMMON_AREA_CENTERS, PAPER_CONFIGURATIONS
from mmsnap_graph.sim import CLEAN
from _fusion import config

T = 0.15
#: The simulator's centroid noise (sim.simulator.CENTROID_NOISE).
NOISE = MeasurementNoise(range_m=0.05, omega_rad=0.08, doppler_mps=0.10)
THREE = {**PAPER_CONFIGURATIONS["B"], "S3": PAPER_CONFIGURATIONS["A"]["S2"]}


def _config(rng):
    pose = np.array([rng.uniform(-5, 5), rng.uniform(-5, 5), rng.uniform(-np.pi, np.pi)])
    r = rng.uniform(1.0, 10.0)
    theta = rng.uniform(-np.radians(70), np.radians(70))
    p = models.local_to_global(np.array([r * np.sin(theta), r * np.cos(theta)]), pose)
    return pose, np.concatenate([p, rng.normal(0.0, 1.5, 2)]), rng.uniform(-0.3, 0.3)


def test_timed_factor_jacobians_match_numerical_derivatives():
    """Pose (through Pose2.retract), state and offset Jacobians of
    ``timed_pose_measurement_factor`` against GTSAM's numerical derivatives,
    and its error equal to the model at ``F(tau) x``."""
    rng = np.random.default_rng(1)
    noise = gtsam.noiseModel.Unit.Create(3)
    kp, ks, kt = gtsam.symbol("x", 1), gtsam.symbol("v", 0), gtsam.symbol("t", 1)
    for _ in range(30):
        pose, state, tau = _config(rng)
        z = models.measurement_model(state, pose)[0] + rng.normal(0, 0.01, 3)
        factor = timed_pose_measurement_factor(kp, ks, kt, z, noise)

        def err(p2, x, t):
            v = gtsam.Values()
            v.insert(kp, p2)
            v.insert(ks, x)
            v.insert(kt, t)
            return factor.unwhitenedError(v)

        p2, t = gtsam.Pose2(*pose), np.array([tau])
        values = gtsam.Values()
        values.insert(kp, p2)
        values.insert(ks, state)
        values.insert(kt, t)
        expected = models.residual(models.measurement_model(shifted_states(state, tau), pose)[0],
                                   z)
        assert_allclose(factor.unwhitenedError(values), expected, atol=1e-12)
        lin = factor.linearize(values)
        a, _ = lin.jacobian()
        assert_allclose(a[:, :3], numericalDerivative31(err, p2, state, t), rtol=1e-5, atol=1e-7)
        assert_allclose(a[:, 3:7], numericalDerivative32(err, p2, state, t), rtol=1e-5, atol=1e-7)
        assert_allclose(a[:, 7:], numericalDerivative33(err, p2, state, t), rtol=1e-5, atol=1e-7)


def test_presolve_with_offsets_matches_the_gtsam_linearization():
    """The pre-solve's Hessian and gradient with clock offsets (states, then
    the pose, then the offset) equal GTSAM's of the same graph."""
    rng = np.random.default_rng(2)
    scene = timed_scene(PAPER_CONFIGURATIONS["C"], time_offsets_s={"S2": 0.05}, n_frames=6,
                        center_m=COMMON_AREA_CENTERS["C"], noise=NOISE, rng=rng)
    sig = NOISE.sigmas
    poses = {"S1": np.zeros(3), "S2": scene.poses["S2"] + [0.1, -0.05, 0.03]}
    states = scene.truth + rng.normal(size=scene.truth.shape) * 0.2
    offsets = {"S2": 0.03}
    prior = np.array([1e3, 1e3, 3.5, 3.5])
    motion = (np.arange(5), np.full(5, T), 0.7)
    problem = PresolveProblem(measurements=scene.measurements, names=["S1", "S2"],
                              reference="S1", sigmas=sig, prior_sigmas=prior, motion=motion)
    hmat, g = normal_equations(problem, poses, states, offsets=offsets)
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    x, t = gtsam.symbol("x", 1), gtsam.symbol("t", 1)
    values.insert(x, gtsam.Pose2(*poses["S2"]))
    values.insert(t, np.array([offsets["S2"]]))
    noise = measurement_noise(sig)
    order = gtsam.Ordering()
    for i in range(6):
        v = gtsam.symbol("v", i)
        values.insert(v, states[i])
        order.push_back(v)
        graph.add(node_measurement_factor(v, np.zeros(3), scene.measurements["S1"][i], noise))
        graph.add(timed_pose_measurement_factor(x, v, t, scene.measurements["S2"][i], noise))
        graph.add(state_prior_factor(v, np.zeros(4), prior))
        if i < 5:
            graph.add(constant_velocity_factor(v, gtsam.symbol("v", i + 1), T, 0.7))
    order.push_back(x)
    order.push_back(t)
    h_ref, eta = graph.linearize(values).hessian(order)
    assert_allclose(hmat.toarray(), h_ref, atol=1e-9 * np.abs(h_ref).max())
    assert_allclose(g, -eta.ravel(), atol=1e-9 * np.abs(eta).max())


def test_simulated_offsets_sample_the_trajectory_at_the_node_times():
    """Noise-free: node S2's frame k is the model at the trajectory's state
    at k T + tau; the interpolated trajectory matches its own grid."""
    rng = np.random.default_rng(3)
    zero = MeasurementNoise(range_m=1e-12, omega_rad=1e-12, doppler_mps=1e-12)
    walk = trajectory_function("straight", COMMON_AREA_CENTERS["B"], duration_s=20.0,
                               rng=np.random.default_rng(4))
    t = np.arange(100) * T
    fine = walk(t + 0.0375)
    coarse = walk(t)
    assert_allclose(fine[:, :2], coarse[:, :2] + 0.0375 * coarse[:, 2:], atol=3e-3)
    scene = timed_scene(PAPER_CONFIGURATIONS["B"], time_offsets_s={"S2": 0.4 * T}, n_frames=50,
                        center_m=COMMON_AREA_CENTERS["B"], noise=zero, kind="turns", rng=rng)
    assert_allclose(scene.measurements["S1"],
                    models.measurement_model(scene.truth, scene.poses["S1"])[0], atol=1e-9)
    # The same draw: the trajectory comes first out of the generator.
    same = trajectory_function("turns", COMMON_AREA_CENTERS["B"], duration_s=50 * T,
                               rng=np.random.default_rng(3))
    late = same(np.arange(50) * T + 0.4 * T)
    assert_allclose(scene.truth, same(np.arange(50) * T), atol=1e-12)
    assert_allclose(scene.measurements["S2"],
                    models.measurement_model(late, scene.poses["S2"])[0], atol=1e-9)
    assert np.max(np.abs(late[:, :2] - scene.truth[:, :2])) > 0.05  # 60 ms at 1 m/s
    with pytest.raises(ValidationError, match="unknown nodes"):
        timed_scene(PAPER_CONFIGURATIONS["B"], time_offsets_s={"S9": 0.1}, rng=rng)


def _calibrate(poses, taus, seed, n_frames, time_offsets=True):
    """Joint calibration of a timed scene, frames shifted by the whole-frame
    lag (as the pose graph's lag search gives) and the rest estimated."""
    rng = np.random.default_rng(seed)
    center = np.array([1.5, 3.5]) if len(poses) > 2 else COMMON_AREA_CENTERS["B"]
    scene = timed_scene(poses, time_offsets_s=taus, n_frames=n_frames, center_m=center,
                        extent_m=1.0 if len(poses) > 2 else 1.5, noise=NOISE, kind="straight",
                        rng=rng)
    lags = {n: -split_offset(taus.get(n, 0.0), T)[0] for n in poses}
    dets = {n: Detections(frame=scene.frame - lags[n], range_m=z[:, 0], omega_rad=z[:, 1],
                          doppler_mps=z[:, 2]) for n, z in scene.measurements.items()}
    options = JointOptions(motion=True, sigma_a_mps2=3.0, time_offsets=time_offsets)
    return scene, joint_calibration(dets, options, noise=NOISE, frame_period_s=T, lag_frames=lags)


def _pose_error(res, scene):
    return np.sqrt(np.mean([np.sum((res.poses[n][:2] - scene.poses[n][:2]) ** 2)
                            for n in scene.poses if n != "S1"]))


@functools.lru_cache(maxsize=None)
def _baseline(n_nodes):
    """The scene of the offset tests without offsets (shared by the two
    2-node cases)."""
    return _calibrate(THREE if n_nodes == 3 else PAPER_CONFIGURATIONS["B"], {}, 11, 2400)


@pytest.mark.slow
@pytest.mark.parametrize("poses, taus", [
    (PAPER_CONFIGURATIONS["B"], {"S2": 0.4 * T}),
    (PAPER_CONFIGURATIONS["B"], {"S2": -1.3 * T}),
    (THREE, {"S2": -1.3 * T, "S3": 0.4 * T}),
], ids=["2-node+0.4", "2-node-1.3", "3-node"])
def test_offsets_are_recovered_within_10_ms(poses, taus):
    """The issue's targets at 150 ms frames with the simulator's centroid
    noise, 2400 frames (6 minutes of back-and-forth walking): every offset
    within 10 ms (and within 4 of its marginal sigmas, ~5-8 ms here), and
    the pose error within 10% of the same scene without offsets."""
    scene, res = _calibrate(poses, taus, 11, 2400)
    base_scene, base = _baseline(len(poses))
    assert res.success and base.success, (res.facts, base.facts)
    assert res.time_offset_s["S1"] == 0.0 and res.time_offset_variances["S1"] == 0.0
    for n in poses:
        if n == "S1":
            continue
        err = res.time_offset_s[n] - taus.get(n, 0.0)
        sd = np.sqrt(res.time_offset_variances[n])
        assert abs(err) < 0.010, (n, err)
        assert abs(err) < 4 * sd, (n, err, sd)
    assert _pose_error(res, scene) <= 1.1 * _pose_error(base, base_scene)


def test_an_offset_moves_the_estimate_by_the_offset():
    """Same noise draw, with and without a 0.4-frame offset on S2: the
    estimated offsets differ by the true offset to within 2 ms (the noise
    is the same; only the timing differs), and the poses agree to 2 cm."""
    scene0, res0 = _calibrate(PAPER_CONFIGURATIONS["B"], {}, 5, 600)
    scene1, res1 = _calibrate(PAPER_CONFIGURATIONS["B"], {"S2": 0.4 * T}, 5, 600)
    shift = res1.time_offset_s["S2"] - res0.time_offset_s["S2"]
    assert abs(shift - 0.4 * T) < 0.002, shift
    assert np.linalg.norm(res1.poses["S2"][:2] - res0.poses["S2"][:2]) < 0.02
    # Without the offset unknown, the result carries the lag only.
    _, plain = _calibrate(PAPER_CONFIGURATIONS["B"], {"S2": -1.3 * T}, 5, 300,
                          time_offsets=False)
    assert plain.time_offset_s["S2"] == pytest.approx(-1 * T)
    assert np.isnan(plain.time_offset_variances["S2"])


def test_timing_argument_errors():
    rng = np.random.default_rng(6)
    scene = timed_scene(PAPER_CONFIGURATIONS["B"], time_offsets_s={}, n_frames=40, noise=NOISE,
                        center_m=COMMON_AREA_CENTERS["B"], rng=rng)
    dets = {n: (scene.frame, z) for n, z in scene.measurements.items()}
    with pytest.raises(ValidationError, match="unknown node"):
        joint_calibration(dets, lag_frames={"S9": 1}, frame_period_s=T)
    with pytest.raises(ValidationError, match="needs frame_period_s"):
        joint_calibration(dets, lag_frames={"S2": 1})
    with pytest.raises(ValidationError, match="time_offsets"):
        joint_calibration(dets, JointOptions(time_offsets="yes"))
    with pytest.raises(ValidationError, match="motion_robust"):
        joint_calibration(dets, JointOptions(motion_robust="tukey"))


# ------------------------------------------------------------------ fusion side
def _aligned_errors(method, tau):
    """RMS errors (range, omega, doppler) against the truth at the
    reference frame times, raw and aligned, noise-free, one walker."""
    rng = np.random.default_rng(7)
    zero = MeasurementNoise(range_m=1e-9, omega_rad=1e-9, doppler_mps=1e-9)
    scene = timed_scene(PAPER_CONFIGURATIONS["B"], time_offsets_s={"S2": tau}, n_frames=200,
                        center_m=COMMON_AREA_CENTERS["B"], noise=zero, kind="straight", rng=rng)
    z = scene.measurements["S2"]
    det = Detections(frame=scene.frame, range_m=z[:, 0], omega_rad=z[:, 1], doppler_mps=z[:, 2])
    out = align_detections(det, tau, T, method=method)
    m = split_offset(tau, T)[0]
    k = out.frame[(out.frame >= 1) & (out.frame < 199)]
    truth = models.measurement_model(scene.truth[k], scene.poses["S2"])[0]
    raw = scene.measurements["S2"][k - m]
    rows = np.searchsorted(out.frame, k)
    return (np.sqrt(np.mean(models.residual(raw, truth) ** 2, axis=0)),
            np.sqrt(np.mean(models.residual(out.measurements[rows], truth) ** 2, axis=0)))


@pytest.mark.parametrize("tau", [0.4 * T, -1.3 * T])
def test_alignment_brings_detections_to_the_reference_time(tau):
    """Doppler: the range error drops at least 10x, the others unchanged;
    interpolation: every component's error drops at least 5x."""
    raw, dop = _aligned_errors("doppler", tau)
    assert dop[0] < 0.1 * raw[0]
    assert_allclose(dop[1:], raw[1:], rtol=1e-12)
    raw, lin = _aligned_errors("interpolate", tau)
    assert np.all(lin < 0.2 * raw), (lin, raw)


def test_align_recording_moves_only_the_offset_nodes_centroids():
    rec = simulate_recording("B", "straight", CLEAN, levels=("centroids",), n_frames=30, seed=1)
    out = align_recording(rec, {"S2": 1.4 * rec.frame_period_s})
    assert out.nodes["S1"].centroids is rec.nodes["S1"].centroids
    assert_allclose(out.nodes["S2"].centroids.frame, rec.nodes["S2"].centroids.frame + 1)
    with pytest.raises(ValidationError, match="unknown nodes"):
        align_recording(rec, {"S9": 0.1})
    with pytest.raises(ValidationError, match="method"):
        align_detections(rec.nodes["S2"].centroids, 0.1, T, method="spline")
    assert dataclasses.replace(rec) is not rec


# ------------------------------------------------------------------ storage
def _timed_calibration(**timing):
    return RecordingCalibration(
        reference="S1", node_names=("S1", "S2"),
        poses={"S1": np.zeros(3), "S2": np.array([0.1, 6.9, 3.1])},
        covariances={"S1": np.zeros((3, 3)), "S2": np.eye(3) * 1e-4},
        lag_frames={"S1": 0, "S2": 1}, method="joint", source="centroids", **timing)


def test_time_offsets_round_trip_through_json_and_hdf5(tmp_path):
    cal = _timed_calibration(time_offset_s={"S1": 0.0, "S2": -0.09},
                             time_offset_variances={"S1": 0.0, "S2": 2.5e-5})
    data = calibration_to_json(cal)
    assert data["nodes"]["S2"]["time_offset_s"] == -0.09
    assert data["nodes"]["S2"]["time_offset_variance_s2"] == 2.5e-5
    assert load_time_offsets(data) == ({"S1": 0.0, "S2": -0.09}, {"S1": 0.0, "S2": 2.5e-5})
    write_calibration_json(tmp_path / "cal.json", cal)
    assert load_time_offsets(tmp_path / "cal.json")[0] == {"S1": 0.0, "S2": -0.09}
    rec = simulate_recording("B", "straight", CLEAN, levels=("centroids",), n_frames=20, seed=2)
    write_recording(tmp_path / "rec.h5", rec)
    write_calibration(tmp_path / "rec.h5", rec, cal)
    offsets, variances = load_time_offsets(tmp_path / "rec.h5")
    assert offsets == {"S1": 0.0, "S2": -0.09} and variances == {"S1": 0.0, "S2": 2.5e-5}
    with h5py.File(tmp_path / "rec.h5", "r") as f:
        assert_allclose(f["calibration/time_offset_s"][()], [0.0, -0.09])
    # Older files: no offsets -> 0, variance NaN; the readers still work.
    old = json.loads(json.dumps(data))
    for entry in old["nodes"].values():
        del entry["time_offset_s"], entry["time_offset_variance_s2"]
    offsets, variances = load_time_offsets(old)
    assert offsets == {"S1": 0.0, "S2": 0.0} and np.isnan(variances["S2"])
    assert read_calibration_json(old).poses.keys() == {"S1", "S2"}
    with h5py.File(tmp_path / "rec.h5", "a") as f:
        del f["calibration/time_offset_s"], f["calibration/time_offset_variance_s2"]
    assert load_time_offsets(tmp_path / "rec.h5")[0] == {"S1": 0.0, "S2": 0.0}
    assert read_calibration(tmp_path / "rec.h5").node_names == ("S1", "S2")
    bad = json.loads(json.dumps(data))
    bad["nodes"]["S2"]["time_offset_s"] = "late"
    with pytest.raises(CalibrationError, match="time_offset_s"):
        load_time_offsets(bad)


def test_end_to_end_calibrate_then_fuse_on_the_reference_clock():
    """A recording whose S2 is 1.3 frames early: the recording calibration's
    lag search finds the whole frame, the joint graph the rest (within 4
    sigmas), and fusing the centroids brought to the reference clock
    (``align_recording``) lowers the fused position error against the truth
    by at least 20% (measured 9.9 -> 6.5 cm at 1200 frames)."""
    scene = timed_scene(PAPER_CONFIGURATIONS["B"], time_offsets_s={"S2": -1.3 * T},
                        n_frames=600, center_m=COMMON_AREA_CENTERS["B"], noise=NOISE,
                        kind="straight", rng=np.random.default_rng(11))
    rec = scene_recording(scene)
    cal = calibrate_recording(rec)
    assert cal.edges[0].lag_frames == 1  # the lag search finds the whole frame
    # The joint graph may move the whole frame to 2 (the rest, 0.3 frame, is
    # beyond joint.LAG_RECENTRE_FRACTION); the total offset is what counts.
    assert cal.lag_frames["S2"] in (1, 2)
    total = cal.time_offset_s["S2"] + 1.3 * T
    assert abs(total) < 4 * np.sqrt(cal.time_offset_variances["S2"]), total
    dets = {n: dataclasses.replace(rec.nodes[n].centroids,
                                   frame=rec.nodes[n].centroids.frame - cal.lag_frames[n])
            for n in rec.node_names}
    res = joint_calibration(dets, JointOptions(motion=True, sigma_a_mps2=3.0, time_offsets=True),
                            initial_poses=cal.poses, noise=NOISE, frame_period_s=T,
                            lag_frames=cal.lag_frames)
    err = res.time_offset_s["S2"] + 1.3 * T
    assert abs(err) < 4 * np.sqrt(res.time_offset_variances["S2"]), err

    def fused_rmse(recording):
        fs = fuse_recording(recording, config(), calibration=NetworkCalibration(node_poses=res.poses), noise=NOISE)
        keep = fs.observed.all(axis=1) & fs.success & (fs.frame >= 0) & (fs.frame < 600)
        d = fs.state[keep, :2] - scene.truth[fs.frame[keep], :2]
        return np.sqrt(np.mean(np.sum(d**2, axis=1)))

    assert fused_rmse(align_recording(rec, res.time_offset_s)) < 0.8 * fused_rmse(rec)


def test_the_range_offset_moves_fused_bodies_to_their_centre():
    """The simulator's near-side reflection (every centroid 0.05 m nearer to
    its radar than the body's centre; no other error source changed), two
    radars at right angles (as in the shared real recordings): the fused
    bodies come out nearer to both radars; fusing with the calibration's
    range offset removes that (radars facing each other would see the two
    offsets cancel along their baseline instead)."""
    from mmsnap_graph.fusion import fuse_recording
    from mmsnap_graph.fusion.recording.timing import offset_ranges
    from mmsnap_graph.sim import simulate_recording
    from mmsnap_graph.sim.options import SimulationOptions
    from mmsnap_graph.sim import RealPhysics

    phys = RealPhysics(static_centroids_per_frame=0, ghost_probability=0, split_probability=0,
                       slow_error_std_m=0.0, reflection_depth_std_m=0.0, p_miss=0.0)
    rec = simulate_recording({"S1": [0.0, 0.0, 0.0], "S2": [5.0, 5.0, np.pi / 2]}, "random",
                             SimulationOptions(physics=phys), levels=("centroids",),
                             n_frames=150, seed=3)
    shifted = offset_ranges(rec, 0.05)
    np.testing.assert_allclose(shifted.nodes["S2"].centroids.range_m,
                               rec.nodes["S2"].centroids.range_m + 0.05)
    truth = np.full((int(rec.truth.frame.max()) + 1, 2), np.nan)
    truth[rec.truth.frame] = rec.truth.state[:, :2]

    def mean_range_error(fused):
        ok = np.asarray(fused.success, bool)
        est = np.asarray(fused.state)[ok, :2]
        true = truth[np.asarray(fused.frame)[ok]]
        near = np.isfinite(true[:, 0]) & (np.linalg.norm(est - true, axis=1) < 1.0)
        est, true = est[near], true[near]
        errs = []
        for pose in (np.asarray(p) for p in rec.truth.node_poses.values()):
            errs.append(np.linalg.norm(est - pose[:2], axis=1)
                        - np.linalg.norm(true - pose[:2], axis=1))
        return float(np.median(errs))

    noise = MeasurementNoise(range_m=0.09, omega_rad=0.08, doppler_mps=0.1)
    plain = fuse_recording(rec, config(), calibration=NetworkCalibration(node_poses=rec.truth.node_poses), noise=noise)
    with_offset = fuse_recording(rec, config(), calibration=NetworkCalibration(
        node_poses=rec.truth.node_poses, range_offset_m=0.05), noise=noise)
    before, after = mean_range_error(plain), mean_range_error(with_offset)
    assert before < -0.015  # measured -0.022 m
    assert abs(after) < abs(before) / 3  # measured -0.006 m
    with pytest.raises(ValidationError, match="range_offset_m must be finite"):
        offset_ranges(rec, 5.0)
