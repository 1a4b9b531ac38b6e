"""``fuse_recording``: a recording fused frame by frame; with
``time_offset_s`` a node whose clock runs late is brought to the reference
clock before fusion."""

import dataclasses

import numpy as np
import pytest

from factors.models import measurement_model
from mmsnap_graph.errors import ValidationError
from mmsnap_graph.fusion import FusionOptions
from mmsnap_graph.fusion.recording.sequence import fuse_recording
from mmsnap_graph.sim import SimulationOptions, network_poses, simulate_recording
from mmsnap_graph.sim.clocks import scene_recording, timed_scene

from _pose_aware import GTSAM_BATCH_TOLERANCE, POSE_COV


def _rmse(rec, fused):
    frame, state = rec.truth.target(0)
    ok = fused.success
    truth = state[np.searchsorted(frame, fused.frame[ok]), :2]
    return float(np.sqrt(np.mean(np.sum((fused.state[ok, :2] - truth) ** 2, axis=1))))


def test_the_offsets_lower_the_fused_error_and_a_zero_offset_changes_nothing():
    poses = network_poses("C")
    tau = -1.3 * 0.15  # S2 1.3 frames early
    scene = timed_scene(poses, time_offsets_s={"S1": 0.0, "S2": tau}, n_frames=300,
                        kind="walk", rng=np.random.default_rng(4))
    rec = scene_recording(scene)
    plain = fuse_recording(rec, node_poses=poses)
    aligned = fuse_recording(rec, node_poses=poses, time_offset_s={"S2": tau})
    assert _rmse(rec, aligned) < 0.8 * _rmse(rec, plain)
    zero = fuse_recording(rec, node_poses=poses, time_offset_s={"S2": 0.0})
    np.testing.assert_array_equal(zero.state, plain.state)
    with pytest.raises(ValidationError, match="S9"):
        fuse_recording(rec, node_poses=poses, time_offset_s={"S9": 0.1})


def test_fuse_recording_passes_pose_covariances_by_name(recording_bc_known_poses):
    by_name = {"S2": POSE_COV[1], "S3": POSE_COV[2]}  # S1 left out: exact
    plain = fuse_recording(recording_bc_known_poses)
    fb = fuse_recording(recording_bc_known_poses, pose_covariances=by_name)
    fg = fuse_recording(recording_bc_known_poses,
                        pose_covariances=by_name,
                        options=FusionOptions(solver="gtsam"))
    ok = plain.success
    assert ok.mean() > 0.9
    np.testing.assert_array_equal(fb.state[ok], plain.state[ok])
    np.testing.assert_allclose(fg.state[ok], fb.state[ok], atol=1e-6)
    assert np.all(fb.covariance[ok, 0, 0] > plain.covariance[ok, 0, 0])
    sig = np.sqrt(np.einsum("fii->fi", fb.covariance[ok]))
    gap = np.abs(fb.covariance[ok] - fg.covariance[ok]) / (sig[:, :, None] * sig[:, None, :])
    assert gap.max() < GTSAM_BATCH_TOLERANCE
    with pytest.raises(ValidationError,
                       match=r"pose_covariances\['S2'\] must be positive definite"):
        fuse_recording(recording_bc_known_poses, pose_covariances={"S2": -np.eye(3)})
    with pytest.raises(ValidationError, match="must be a mapping"):
        fuse_recording(recording_bc_known_poses, pose_covariances=POSE_COV)


def _jtwj(fused, i):
    """J^T W J of row ``i`` at its estimate, from the measurement model."""
    w = np.diag(1.0 / fused.noise_sigmas**2)
    out = np.zeros((4, 4))
    for n in np.flatnonzero(fused.observed[i] & ~fused.rejected[i]):
        _, jac = measurement_model(fused.state[i], fused.node_poses[n])
        out += jac.T @ w @ jac
    return out


@pytest.mark.parametrize("which", ["fused_b_map", "fused_b_ml"])
@pytest.mark.parametrize("solver", ["vectorized", "gtsam"])
def test_information_is_jtwj_at_the_estimate(which, solver, recording_b_known_poses, request):
    fused = request.getfixturevalue(which)
    if solver == "gtsam":
        kw = {} if fused.mode == "map" else {"mode": "ml", "prior": None}
        fused = fuse_recording(recording_b_known_poses,
                               progress=False,
                               **kw,
                               options=FusionOptions(solver="gtsam"))
    rows = np.flatnonzero(fused.success)
    assert rows.size > 50
    for i in rows:
        expect = _jtwj(fused, i)
        # Measured: relative errors ~1e-14 (the Laplace covariance is the
        # inverse Gauss-Newton information at the estimate).
        np.testing.assert_allclose(fused.information[i], expect, rtol=1e-8,
                                   atol=1e-10 * np.abs(expect).max())


def test_information_vector_gives_the_prior_free_state(fused_b_map, fused_b_ml):
    """Y^-1 y of the MAP rows is the ML estimate to first order: far closer
    to it than the MAP state is."""
    both = np.flatnonzero(fused_b_map.success & fused_b_ml.success & fused_b_map.observed.all(axis=1))
    assert both.size > 50
    d_free, d_map = [], []
    for i in both:
        free = np.linalg.solve(fused_b_map.information[i], fused_b_map.information_vector[i])
        for x, out in ((free, d_free), (fused_b_map.state[i], d_map)):
            e = x - fused_b_ml.state[i]
            out.append(e @ np.linalg.solve(fused_b_ml.covariance[i], e))
    # Measured: median Mahalanobis^2 ~1e-11 (prior-free) against ~7e-4 (MAP).
    assert np.median(d_free) < 1e-3 * np.median(d_map)
    assert np.max(d_free) < 1e-6
    # ML: Y is the inverse covariance and Y^-1 y the state itself.
    i = both[0]
    np.testing.assert_allclose(fused_b_ml.information[i] @ fused_b_ml.covariance[i], np.eye(4),
                               atol=1e-8)
    np.testing.assert_allclose(np.linalg.solve(fused_b_ml.information[i],
                                               fused_b_ml.information_vector[i]),
                               fused_b_ml.state[i], rtol=1e-9)


def test_fuse_recording_carries_the_recording_clock():
    """In memory too (not only through write_fused): time_s = frame x period,
    and the wall-clock origin of a time-stamped recording."""
    rec = simulate_recording("B", options=SimulationOptions(physics=None, known_poses=True,
                                                            frame_period_s=0.05),
                             levels=("centroids",), n_frames=12)
    fused = fuse_recording(rec)
    np.testing.assert_allclose(fused.time_s, fused.frame * 0.05)
    assert fused.frame_period_s == 0.05 and fused.time_origin_s is None
    stamped = dataclasses.replace(rec, metadata={**rec.metadata, "time_origin_s": 1.7e9})
    assert fuse_recording(stamped).time_origin_s == 1.7e9
