"""``fuse_recording``: a recording fused frame by frame; with
``time_offset_s`` a node whose clock runs late is brought to the reference
clock before fusion."""

import dataclasses

import numpy as np
import pytest

from factors.models import measurement_model
from mmsnap_graph.data.noise import GaussianPrior, MeasurementNoise
from mmsnap_graph.data.results import Status
from mmsnap_graph.evaluation import state_errors
from mmsnap_graph.fusion.recording.sequence import recording_poses
from mmsnap_graph.errors import ValidationError
from mmsnap_graph.fusion import FusionOptions, NetworkCalibration
from mmsnap_graph.fusion.recording.sequence import fuse_recording
from mmsnap_graph.sim import SimulationOptions, network_poses, simulate_recording
from mmsnap_graph.sim.clocks import scene_recording, timed_scene

from _pose_aware import GTSAM_BATCH_TOLERANCE, POSE_COV
from mmsnap_graph.fusion.config import AssociationOptions, FusionConfig
from _fusion import config, solved


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
    plain = fuse_recording(rec, config(), calibration=NetworkCalibration(node_poses=poses))
    aligned = fuse_recording(rec, config(), calibration=NetworkCalibration(
        node_poses=poses, time_offset_s={"S2": tau}))
    assert _rmse(rec, aligned) < 0.8 * _rmse(rec, plain)
    zero = fuse_recording(rec, config(), calibration=NetworkCalibration(
        node_poses=poses, time_offset_s={"S2": 0.0}))
    np.testing.assert_array_equal(zero.state, plain.state)
    with pytest.raises(ValidationError, match="S9"):
        fuse_recording(rec, config(), calibration=NetworkCalibration(
            node_poses=poses, time_offset_s={"S9": 0.1}))


def test_fuse_recording_passes_pose_covariances_by_name(recording_bc_known_poses):
    by_name = {"S2": POSE_COV[1], "S3": POSE_COV[2]}  # S1 left out: exact
    plain = fuse_recording(recording_bc_known_poses, config())
    fb = fuse_recording(recording_bc_known_poses, config(), calibration=NetworkCalibration(pose_covariances=by_name))
    fg = fuse_recording(recording_bc_known_poses, config(solver="gtsam"), calibration=NetworkCalibration(pose_covariances=by_name))
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
        fuse_recording(recording_bc_known_poses, config(), calibration=NetworkCalibration(pose_covariances={"S2": -np.eye(3)}))
    with pytest.raises(ValidationError, match="must be a mapping"):
        NetworkCalibration(pose_covariances=POSE_COV)


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
        fused = fuse_recording(recording_b_known_poses, config(solver="gtsam", **kw),
                               progress=False)
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
    fused = fuse_recording(rec, config())
    np.testing.assert_allclose(fused.time_s, fused.frame * 0.05)
    assert fused.frame_period_s == 0.05 and fused.time_origin_s is None
    stamped = dataclasses.replace(rec, metadata={**rec.metadata, "time_origin_s": 1.7e9})
    assert fuse_recording(stamped, config()).time_origin_s == 1.7e9


@pytest.fixture
def recordings(two_target_recordings):
    """Two walking targets, 10 % missed centroids, per configuration (conftest)."""
    return two_target_recordings


@pytest.mark.parametrize("net", ["A", "B"])
@pytest.mark.parametrize("mode", ["map", "ml"])
def test_batch_and_gtsam_agree_on_every_frame(recordings, net, mode):
    rec = recordings[net]
    fb = fuse_recording(rec, config(mode=mode, solver="vectorized"))
    fg = fuse_recording(rec, config(mode=mode, solver="gtsam"))
    np.testing.assert_array_equal(fb.frame, fg.frame)
    np.testing.assert_array_equal(fb.success, fg.success)
    # Both solvers report the same Status codes (carried by the results).
    np.testing.assert_array_equal(fb.status, fg.status)
    ok = fb.success
    np.testing.assert_allclose(fb.state[ok], fg.state[ok], atol=1e-6)
    np.testing.assert_allclose(fb.covariance[ok], fg.covariance[ok], atol=1e-6)
    # Frames seen by one node only: fused with what there is (MAP), or
    # flagged (ML, 3 measurements for 4 unknowns).
    single = fb.observed.sum(axis=1) == 1
    assert single.any()
    assert fb.success[single].all() if mode == "map" else not fb.success[single].any()


def test_configuration_c_batch_at_least_as_converged_as_gtsam(recordings):
    """Near the line through both radars GTSAM's LM stops in a flat valley a
    few 1e-6 short of the minimum; the batch solver's cost is never higher."""
    rec = recordings["C"]
    fb = fuse_recording(rec, config(solver="vectorized"))
    fg = fuse_recording(rec, config(solver="gtsam"))
    np.testing.assert_array_equal(fb.success, fg.success)
    ok = fb.success
    assert np.all(fb.final_cost[ok] <= fg.final_cost[ok] + 1e-12 * np.maximum(1, fg.final_cost[ok]))
    close = np.all(np.abs(fb.state - fg.state) <= 1e-6, axis=1)
    assert close[ok].mean() > 0.9
    np.testing.assert_allclose(fb.state[ok], fg.state[ok], atol=1e-4)


def test_targets_are_recovered_with_their_labels(recordings):
    rec = recordings["B"]
    fused = fuse_recording(rec, config())
    assert set(np.unique(fused.label)) <= {-1, 0, 1}
    assert (fused.label >= 0).mean() > 0.9
    for label in (0, 1):
        rows = fused.rows_of_label(label)
        rows = rows[fused.success[rows]]
        _, truth = rec.truth.target(label)
        err = state_errors(fused.state[rows], truth[fused.frame[rows]])
        # Paper Table III, configuration B: 0.14-0.17 m and 0.27-0.34 m/s.
        assert err.position_rmse_m < 0.3 and err.velocity_rmse_mps < 0.6


def test_grid_covariance_matches_the_gtsam_solve(recordings):
    rec = recordings["B"]
    fused = fuse_recording(rec, config(covariance="grid", grid_points_per_axis=7))
    rows = np.flatnonzero(fused.success)[:4]
    obs = fused.observed
    for i in rows:
        z = np.zeros((2, 3))
        for n, name in enumerate(fused.node_names):
            if obs[i, n]:
                z[n] = rec.nodes[name].centroids.measurements[fused.detection_index[i, n]]
        ref = solved(fused.node_poses, z, observed=obs[i],
                     options=FusionOptions(covariance="grid", grid_points_per_axis=7))
        np.testing.assert_allclose(fused.covariance[i], ref.grid_covariance[0], rtol=1e-4,
                                   atol=1e-7)
        np.testing.assert_allclose(fused.laplace_covariance[i], ref.covariance[0], atol=1e-6)


@pytest.mark.parametrize(
    "build, match",
    [
        (lambda: FusionOptions(covariance="exact"), "covariance must be 'laplace' or 'grid'"),
        (lambda: FusionOptions(covariance="both"), "covariance must be 'laplace' or 'grid'"),
        (lambda: FusionOptions(solver="scipy"), "solver must be 'gtsam' or 'vectorized' or 'scalar'"),
        (lambda: FusionOptions(solver="batch"), "'batch' is now called 'vectorized'"),
        (lambda: AssociationOptions(source="cube"), "source must be 'centroids' or 'point_cloud'"),
        (lambda: FusionOptions(block_rows=0), "block_rows=0 must be an integer >= 1"),
        (lambda: FusionConfig(prior="paper"), "prior must be a GaussianPrior or None"),
        (lambda: FusionConfig(solve="laplace"), "solve must be a FusionOptions, got str"),
    ],
)
def test_fusion_config_invalid_arguments(build, match):
    with pytest.raises(ValidationError, match=match):
        build()


@pytest.mark.parametrize(
    "config_, match",
    [
        (FusionConfig(association=AssociationOptions(source="point_cloud")),
         "no node of the recording has point_cloud"),
        ("laplace", "config must be a FusionConfig, got str"),
    ],
)
def test_fuse_recording_invalid_arguments(recordings, config_, match):
    with pytest.raises(ValidationError, match=match):
        fuse_recording(recordings["A"], config_)


def test_vectorized_grouping_equals_frame_by_frame_association(recordings):
    """The fast path of group_detections (one detection per node, one gate)
    gives what associate_frame gives frame by frame."""
    from mmsnap_graph.fusion.association import associate_frame
    from mmsnap_graph.fusion.recording.sequence import group_detections

    rec = simulate_recording("A", "random",
                             SimulationOptions(physics=None, known_poses=True, centroid_p_miss=0.2),
                             levels=("centroids",), n_frames=80, seed=2)
    import dataclasses

    from mmsnap_graph.data.recording import Detections

    # A false alarm far from the target in frame 5 (S2): that frame takes the
    # per-frame path, the others the vectorized one.
    c2 = rec.nodes["S2"].centroids
    extra = Detections(frame=np.append(c2.frame, 5), range_m=np.append(c2.range_m, 9.0),
                       omega_rad=np.append(c2.omega_rad, 2.5), doppler_mps=np.append(c2.doppler_mps, 0.0))
    rec = rec.with_node(dataclasses.replace(rec.nodes["S2"], centroids=extra))
    poses = recording_poses(rec)
    groups = group_detections(rec, poses, MeasurementNoise())
    assert np.count_nonzero(groups.frame == 5) == 2
    cents = [rec.nodes[n].centroids for n in rec.node_names]
    rows = []
    for f in np.unique(np.concatenate([c.frame for c in cents])):
        idx = [np.flatnonzero(c.frame == f) for c in cents]
        a = associate_frame([c.measurements[i] for c, i in zip(cents, idx)], poses, MeasurementNoise())
        for g, members in enumerate(a.members):
            rows.append((f, g, *[idx[n][m] if m >= 0 else -1 for n, m in enumerate(members)]))
    expected = np.array(rows)
    np.testing.assert_array_equal(groups.frame, expected[:, 0])
    np.testing.assert_array_equal(groups.target, expected[:, 1])
    np.testing.assert_array_equal(groups.detection_index, expected[:, 2:])


def test_fuse_recording_takes_the_calibration_as_one_object(recording_bc_known_poses):
    rec = recording_bc_known_poses
    with pytest.raises(ValidationError, match="calibration must be a NetworkCalibration, got dict"):
        fuse_recording(rec, config(), calibration={"node_poses": rec.truth.node_poses})
    with pytest.raises(TypeError, match="node_poses"):
        fuse_recording(rec, config(node_poses=rec.truth.node_poses))
    moved = {n: np.asarray(p) + [0.2, 0.0, 0.0] for n, p in rec.truth.node_poses.items()}
    fused = fuse_recording(rec, config(), calibration=NetworkCalibration(node_poses=moved))
    np.testing.assert_array_equal(fused.node_poses, np.stack([moved[n] for n in rec.node_names]))
