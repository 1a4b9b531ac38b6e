"""Per-node measurement noise in the one-shot solvers (issue 11, item 1's solver side).

``noise`` is one MeasurementNoise (every node) or one per node; the GTSAM
path (fuse_frame) and the batch path (fuse_batch) must agree, with the robust
modes too; fuse_recording takes a mapping by node name; the association gates
each node's detections with its own sigmas.
"""

from __future__ import annotations

import numpy as np
import pytest
from mmsnap_graph.evaluation import chi2_mean_interval, nees

from _shared import PAPER_NOISE, PAPER_PRIOR, POSES_BC
from factors.models import measurement_model, predict_measurements, wrap_angle
from mmsnap_graph.fusion import FusionOptions, LevenbergMarquardtSettings
from mmsnap_graph import MeasurementNoise
from mmsnap_graph.errors import ValidationError
from mmsnap_graph.fusion.association import associate_frame
from mmsnap_graph.fusion.frame_problem import FrameProblem, initial_states
from mmsnap_graph.fusion import problem
from mmsnap_graph.fusion.problem import check_node_noise
from mmsnap_graph.fusion.recording.sequence import fuse_recording, group_detections
from mmsnap_graph.fusion.stream.frame_stream import FrameStream
from mmsnap_graph.sim import simulate_recording
from mmsnap_graph.sim import SimulationOptions
from _fusion import config, frame_of, solved, stream_config


def fuse_batch(poses, z, **kwargs):
    """The vectorized solver through the contract."""
    return solved(poses, z, solver="vectorized", **kwargs)


def fuse_frame(poses, z, **kwargs):
    """GTSAM through the contract, one frame (its fields without the frame axis)."""
    return frame_of(solved(poses, z, solver="gtsam", **kwargs))

#: Three nodes with sigmas far apart (node 1 has a poor range, node 2 a poor Doppler).
NOISES = (
    MeasurementNoise(range_m=0.02, omega_rad=0.3, doppler_mps=0.05),
    MeasurementNoise(range_m=0.25, omega_rad=0.6, doppler_mps=0.1),
    MeasurementNoise(range_m=0.05, omega_rad=0.15, doppler_mps=0.6),
)
SIGMAS = np.array([m.sigmas for m in NOISES])


def _frames(rng, n_frames, noises=NOISES, p_miss=0.0):
    """Targets in the 3-node network's common area, measured with each node's sigmas."""
    sig = np.array([m.sigmas for m in noises])
    states = np.column_stack([rng.uniform(1.0, 4.0, n_frames), rng.uniform(1.5, 5.5, n_frames),
                              rng.normal(0.0, 0.7, (n_frames, 2))])
    z = np.stack([predict_measurements(states, p) for p in POSES_BC], axis=1)
    z = z + rng.normal(size=z.shape) * sig
    z[..., 1] = wrap_angle(z[..., 1])
    obs = rng.random((n_frames, 3)) >= p_miss
    obs[obs.sum(axis=1) == 0, 0] = True
    return states, z, obs


# ----------------------------------------------------------------------------
# Validation


@pytest.mark.parametrize(
    "noise, match",
    [
        ([PAPER_NOISE] * 2, r"noise must hold one MeasurementNoise per node \(3\), got 2"),
        ([PAPER_NOISE, "x", PAPER_NOISE], r"noise\[1\] must be a MeasurementNoise, got str"),
        ((0.1, 0.1, 0.1), "noise must be a MeasurementNoise, got tuple"),
        ({"S1": PAPER_NOISE}, "a mapping by node name is for fuse_recording"),
    ],
)
def test_fuse_frame_and_fuse_batch_reject_bad_per_node_noise(noise, match):
    rng = np.random.default_rng(0)
    _, z, _ = _frames(rng, 2)
    with pytest.raises(ValidationError, match=match):
        fuse_frame(POSES_BC, z[0], noise=noise)
    with pytest.raises(ValidationError, match=match):
        fuse_batch(POSES_BC, z, noise=noise)


def test_check_node_noise_by_name_names_the_missing_node():
    names = ("S1", "S2", "S3")
    got = check_node_noise({"S3": NOISES[2], "S1": NOISES[0], "S2": NOISES[1]}, 3, names)
    assert got == NOISES
    with pytest.raises(ValidationError, match="no MeasurementNoise for node 'S2'"):
        check_node_noise({"S1": NOISES[0], "S3": NOISES[2]}, 3, names)
    with pytest.raises(ValidationError, match=r"noise\['S3'\] must be a MeasurementNoise"):
        check_node_noise({"S1": NOISES[0], "S2": NOISES[1], "S3": 0.1}, 3, names)


# ----------------------------------------------------------------------------
# One noise or N equal ones: the same numbers


def test_n_equal_noises_give_exactly_the_single_noise_result():
    rng = np.random.default_rng(1)
    _, z, obs = _frames(rng, 40, noises=(PAPER_NOISE,) * 3, p_miss=0.2)
    one = fuse_batch(POSES_BC, z, observed=obs, noise=PAPER_NOISE)
    many = fuse_batch(POSES_BC, z, observed=obs, noise=[PAPER_NOISE] * 3)
    np.testing.assert_array_equal(many.state, one.state)
    np.testing.assert_array_equal(many.covariance, one.covariance)
    for f in range(5):
        a = fuse_frame(POSES_BC, z[f], observed=obs[f], noise=PAPER_NOISE)
        b = fuse_frame(POSES_BC, z[f], observed=obs[f], noise=(PAPER_NOISE,) * 3)
        np.testing.assert_array_equal(a.state, b.state)
        np.testing.assert_array_equal(a.covariance, b.covariance)


# ----------------------------------------------------------------------------
# GTSAM and batch agree; the covariance is the per-node information's inverse


def _assert_agree(res_b, f, res_g, rtol=1e-6):
    assert res_b.success[f] == res_g.success
    assert res_b.status[f] == res_g.status
    if not res_g.success:
        return
    sig = np.sqrt(np.diag(res_g.covariance))
    np.testing.assert_allclose(res_b.state[f], res_g.state, rtol=0, atol=rtol * (1 + sig.max()))
    np.testing.assert_allclose(res_b.covariance[f] / np.outer(sig, sig),
                               res_g.covariance / np.outer(sig, sig), rtol=0, atol=rtol)


@pytest.mark.parametrize("prior", [PAPER_PRIOR, None], ids=["map", "ml"])
def test_per_node_noise_gtsam_and_batch_agree(prior):
    rng = np.random.default_rng(2)
    _, z, obs = _frames(rng, 60, p_miss=0.15)
    res = fuse_batch(POSES_BC, z, observed=obs, noise=NOISES, prior=prior)
    assert res.success.mean() > 0.9
    for f in range(z.shape[0]):
        _assert_agree(res, f, fuse_frame(POSES_BC, z[f], observed=obs[f], noise=NOISES,
                                         prior=prior))


def test_per_node_covariance_is_the_inverse_of_the_per_node_information():
    """At the solution, the Laplace covariance is ``(sum_i J_i^T W_i J_i + prior)^-1``
    with each node's own ``W_i``; one shared noise would give another matrix."""
    rng = np.random.default_rng(3)
    _, z, _ = _frames(rng, 10)
    res = fuse_batch(POSES_BC, z, noise=NOISES)
    assert res.success.all()
    info = np.tile(PAPER_PRIOR.information, (10, 1, 1))
    for n, pose in enumerate(POSES_BC):
        _, jac = measurement_model(res.state, pose)
        info += np.einsum("fki,k,fkj->fij", jac, 1.0 / SIGMAS[n] ** 2, jac)
    np.testing.assert_allclose(res.covariance, np.linalg.inv(info), rtol=1e-8, atol=1e-14)
    shared = fuse_batch(POSES_BC, z, noise=NOISES[0])
    assert np.abs(shared.covariance - res.covariance).max() > 1e-4


def test_initial_velocity_weighs_each_nodes_doppler_by_its_sigma():
    """The vectorized and the per-frame initial values agree with per-node sigmas."""
    rng = np.random.default_rng(4)
    _, z, obs = _frames(rng, 30, p_miss=0.2)
    x0 = initial_states(FrameProblem(poses=POSES_BC, measurements=z, observed=obs, noise=NOISES))
    res = fuse_batch(POSES_BC,
                     z,
                     observed=obs,
                     noise=NOISES,
                     options=FusionOptions(lm=LevenbergMarquardtSettings(max_steps=1)))
    np.testing.assert_allclose(res.initial_state, x0, rtol=0, atol=1e-12)
    for f in range(5):
        r = fuse_frame(POSES_BC, z[f], observed=obs[f], noise=NOISES)
        np.testing.assert_allclose(r.initial_state, x0[f], rtol=0, atol=1e-12)
    shared = initial_states(FrameProblem(poses=POSES_BC, measurements=z, observed=obs))
    assert np.abs(x0[:, 2:] - shared[:, 2:]).max() > 1e-3


@pytest.mark.parametrize("robust", ["gate", "huber", "cauchy"])
def test_robust_modes_with_per_node_noise_agree(robust):
    rng = np.random.default_rng(5)
    _, z, obs = _frames(rng, 40)
    # Every fourth frame: a ghost range on node 2 (40 of its sigmas).
    z[::4, 2, 0] += 40 * SIGMAS[2, 0]
    res = fuse_batch(POSES_BC, z, observed=obs, noise=NOISES, robust=robust)
    for f in range(z.shape[0]):
        r = fuse_frame(POSES_BC, z[f], observed=obs[f], noise=NOISES, robust=robust)
        _assert_agree(res, f, r, rtol=1e-5)
        np.testing.assert_array_equal(res.rejected[f], r.rejected)
    if robust == "gate":
        # Each node's residual is whitened by its own sigmas: the ghost frames
        # fail the test (rejected, or flagged when the leave-one-out refits are
        # ambiguous); the clean ones mostly pass.
        ghost = (res.status[::4] != 0) | res.rejected[::4].any(axis=1)
        assert ghost.mean() >= 0.8
        assert (res.status[1::4] == 0).mean() >= 0.8


# ----------------------------------------------------------------------------
# Consistency: per-node noise gives honest covariances, a shared one does not


def test_per_node_noise_nees_in_band_and_a_shared_noise_out_of_band():
    rng = np.random.default_rng(6)
    n = 3000
    states, z, _ = _frames(rng, n)
    band = chi2_mean_interval(4, n, 0.95)

    def mean_nees(noise):
        res = fuse_batch(POSES_BC, z, noise=noise)
        e = (res.state - states)[res.success]
        return float(np.mean(nees(e, res.covariance[res.success])))

    per_node = mean_nees(NOISES)
    shared = mean_nees(MeasurementNoise(range_m=SIGMAS[:, 0].mean(), omega_rad=SIGMAS[:, 1].mean(),
                                   doppler_mps=SIGMAS[:, 2].mean()))
    assert band[0] < per_node < band[1], (per_node, band)
    assert not band[0] < shared < band[1], (shared, band)


# ----------------------------------------------------------------------------
# Association, fuse_recording and the stream


def test_association_gates_each_node_with_its_own_sigmas():
    """Two detections 0.6 m apart: one target for a node with a poor range, two otherwise."""
    x = np.array([2.5, 3.5, 0.0, 0.0])
    z0 = predict_measurements(x, POSES_BC[0])[None]
    x1 = x + np.array([0.0, 0.6, 0.0, 0.0])  # along node 1's line of sight (from (5, 5))
    x1[:2] = x[:2] + 0.6 * (x[:2] - POSES_BC[1, :2]) / np.linalg.norm(x[:2] - POSES_BC[1, :2])
    z1 = predict_measurements(x1, POSES_BC[1])[None]
    empty = np.zeros((0, 3))
    tight = MeasurementNoise(range_m=0.05, omega_rad=0.05)
    loose = MeasurementNoise(range_m=1.0, omega_rad=0.05)
    assert len(associate_frame([z0, z1, empty], POSES_BC, tight)) == 2
    assert len(associate_frame([z0, z1, empty], POSES_BC, [tight, loose, tight])) == 1
    with pytest.raises(ValidationError, match="one MeasurementNoise per node"):
        associate_frame([z0, z1, empty], POSES_BC, [tight, loose])


@pytest.fixture(scope="module")
def recording_3():
    network = {"S1": POSES_BC[0], "S2": POSES_BC[1], "S3": POSES_BC[2]}
    return simulate_recording(network, "random",
                              SimulationOptions(physics=None, known_poses=True, centroid_p_miss=0.1),
                              levels=("centroids",), n_frames=60, seed=7)


def test_fuse_recording_validates_the_noise_once(recording_3, monkeypatch):
    """The driver validates the noise once; the problem, the association and
    the solvers take the validated NodeNoise as it is (was: 185 validations
    of a 200-frame recording, one per frame the association groups alone)."""
    import sys

    real = problem.check_node_noise
    validated = []

    def counting(noise, *args, **kwargs):
        if type(noise) is not problem.NodeNoise:
            validated.append(noise)
        return real(noise, *args, **kwargs)

    for module in list(sys.modules.values()):
        if getattr(module, "check_node_noise", None) is real:
            monkeypatch.setattr(module, "check_node_noise", counting)
    nn = real(NOISES, 3)
    assert real(nn, 3) is nn
    fuse_recording(recording_3, config(robust="gate"), noise=dict(zip(recording_3.node_names,
                                                                         NOISES)))
    assert len(validated) == 1


def test_fuse_recording_takes_a_noise_mapping_with_both_solvers(recording_3):
    by_name = dict(zip(recording_3.node_names, NOISES))
    fb = fuse_recording(recording_3, config(solver="vectorized"), noise=by_name)
    fg = fuse_recording(recording_3, config(solver="gtsam"), noise=by_name)
    np.testing.assert_array_equal(fb.status, fg.status)
    ok = fb.success
    assert ok.mean() > 0.9
    np.testing.assert_allclose(fb.state[ok], fg.state[ok], atol=1e-6)
    np.testing.assert_allclose(fb.covariance[ok], fg.covariance[ok], rtol=1e-5, atol=1e-10)
    np.testing.assert_array_equal(fb.noise_sigmas, SIGMAS)
    plain = fuse_recording(recording_3, config(solver="vectorized"))
    assert plain.noise_sigmas.shape == (3,)
    assert np.abs(plain.covariance[ok] - fb.covariance[ok]).max() > 1e-4
    # The grouping used the per-node sigmas (one call, the same groups).
    groups = group_detections(recording_3, fb.node_poses, by_name)
    np.testing.assert_array_equal(groups.detection_index, fb.detection_index)


def test_fuse_recording_names_the_node_without_noise(recording_3):
    with pytest.raises(ValidationError, match="no MeasurementNoise for node 'S3'"):
        fuse_recording(recording_3, config(), noise={"S1": NOISES[0], "S2": NOISES[1]})
    with pytest.raises(ValidationError, match="per-node noise and pose_covariances need"):
        fuse_recording(recording_3, config(covariance="grid"), noise=dict(zip(recording_3.node_names, NOISES)))


@pytest.mark.parametrize("solver", ["gtsam", "vectorized"])
def test_frame_stream_takes_per_node_noise(recording_3, solver):
    by_name = dict(zip(recording_3.node_names, NOISES))
    stream = FrameStream(recording_3.node_names, POSES_BC, config=stream_config(solver=solver), noise=by_name)
    assert stream.noise == NOISES
    rng = np.random.default_rng(8)
    states, z, _ = _frames(rng, 5)
    for k in range(5):
        update = stream.push(0.15 * (k + 1), [z[k, n][None] for n in range(3)])
        assert update.ok and update.state.shape == (1, 4)
        ref = fuse_frame(POSES_BC, z[k], noise=NOISES)
        np.testing.assert_allclose(update.state[0], ref.state, atol=1e-6)


def test_a_heading_in_degrees_is_a_validation_error_saying_radians():
    # phi = 180 (degrees) "fits" as 180 rad = 0.5 rad mod 2 pi: it gave
    # success=True. Every pose entry point now refuses |phi| > 2 pi.
    from mmsnap_graph.calibration.monitor.decalibration import DecalibrationMonitor
    from mmsnap_graph.data.recording import NodeData
    from mmsnap_graph.calibration import joint_calibration
    poses = np.array(POSES_BC, dtype=float)
    z = predict_measurements(np.array([2.0, 0.3, 3.0, -0.2]), poses)
    poses[1, 2] = 180.0
    with pytest.raises(ValidationError, match=r"node_poses\[1\].*radians"):
        fuse_frame(poses, z)
    with pytest.raises(ValidationError, match="radians"):
        NodeData(name="S2", pose=(0.0, 7.0, 180.0))
    with pytest.raises(ValidationError, match=r"node_poses\[S2\].*radians"):
        DecalibrationMonitor({"S1": (0.0, 0.0, 0.0), "S2": (0.0, 7.0, -270.0)})
    frames = np.arange(5)
    with pytest.raises(ValidationError, match=r"initial_poses\['S2'\].*radians"):
        joint_calibration({"S1": (frames, np.ones((5, 3))), "S2": (frames, np.ones((5, 3)))},
                          initial_poses={"S2": (0.0, 7.0, 180.0)})
    NodeData(name="S2", pose=(0.0, 7.0, -2 * np.pi))  # one turn is still radians
