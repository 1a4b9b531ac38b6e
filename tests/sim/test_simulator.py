"""simulate_recording: truth and generated measurements agree within the noise."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from factors.models import measurement_model, wrap_angle
from mmsnap_graph import ConfigurationError, ValidationError
from mmsnap_graph.io import read_recording, write_recording
from mmsnap_graph.data.radar_config import TABLE_I
from mmsnap_graph.sim import CENTROID_NOISE, PointCloudModel, network_poses, simulate_recording
from mmsnap_graph.sim.networks import in_field_of_view
from mmsnap_graph.sim import CLEAN, SimulationOptions


@pytest.fixture
def rec_b(recording_b_point_cloud):
    return recording_b_point_cloud


def _truth_h(rec, name, frames, target_ids):
    state = rec.truth.state.reshape(-1, len(np.unique(rec.truth.frame)), 4)
    pose = rec.truth.node_poses[name]
    return measurement_model(state[target_ids, frames], pose)[0]


def test_truth_holds_torso_states_and_poses(rec_b):
    t = rec_b.truth
    assert t.state.shape == (600, 4) and set(t.target_id.tolist()) == {0}
    assert_array_equal(t.frame, np.arange(600))
    for name, pose in network_poses("B").items():
        assert_allclose(t.node_poses[name], pose)
        assert rec_b.nodes[name].pose is None  # unknown until calibrated
    assert rec_b.frame_period_s == 0.15
    assert rec_b.node_names == ["S1", "S2"]


def test_centroids_agree_with_truth_within_stated_noise(rec_b):
    noise = CENTROID_NOISE
    for name in rec_b.node_names:
        c = rec_b.nodes[name].centroids
        assert len(c) == 600  # the common area is in view of both nodes
        h = _truth_h(rec_b, name, c.frame, c.target_id)
        e = c.measurements - h
        e[:, 1] = wrap_angle(e[:, 1])
        z = e / noise.sigmas
        n = len(c)
        # Unbiased (4 sigma of the mean) and of the stated variance (chi2_1
        # mean has std sqrt(2/n) = 0.06).
        assert np.all(np.abs(z.mean(axis=0)) < 4 / np.sqrt(n))
        assert_allclose((z ** 2).mean(axis=0), 1.0, atol=0.25)
        assert np.all(c.snr_db > 20)


def test_out_of_view_frames_have_no_centroid():
    # Walk along x at y = 3 from x = -8 to 8: S1 sees |x| <= 3 tan(60 deg).
    n = 100
    x = np.linspace(-8, 8, n)
    states = np.stack([x, np.full(n, 3.0), np.full(n, 16 / (n - 1) / 0.15), np.zeros(n)], axis=1)
    rec = simulate_recording("C", states,
                             SimulationOptions(physics=None, point_cloud_model=PointCloudModel(false_alarms_per_frame=0.0)),
                             levels=("centroids", "point_cloud"), seed=1)
    for name, pose in network_poses("C").items():
        seen = in_field_of_view(states[:, :2], pose)
        assert 0 < seen.sum() < n
        assert_array_equal(np.unique(rec.nodes[name].centroids.frame), np.flatnonzero(seen))
        pc = rec.nodes[name].point_cloud
        # Limbs reach < 1 m from the torso: no point unless the torso is near the view.
        near = seen.copy()
        for dx in (-1.0, 1.0):
            near |= in_field_of_view(states[:, :2] + [dx, 0.0], pose)
        assert len(pc) > 0
        assert set(np.unique(pc.frame).tolist()) <= set(np.flatnonzero(near).tolist())


def test_missed_detections_rate():
    rec = simulate_recording("C", "straight",
                             SimulationOptions(physics=None, centroid_p_miss=0.2),
                             levels=("centroids",), seed=2)
    n = len(rec.nodes["S1"].centroids)
    # Binomial(600, 0.8): std 9.8.
    assert abs(n - 480) < 40


def test_point_cloud_has_limb_doppler_spread_and_false_alarms(rec_b):
    for name in rec_b.node_names:
        pc = rec_b.nodes[name].point_cloud
        real = pc.target_id == 0
        fa = pc.target_id == -1
        # About one false alarm per frame (Poisson mean 1 over 600 frames).
        assert abs(fa.sum() - 600) < 4 * np.sqrt(600)
        # Many detections per frame from the extended body.
        per_frame = np.bincount(pc.frame[real], minlength=600)
        assert per_frame.mean() > 8
        # Doppler spread around the torso Doppler: limbs move faster.
        h = _truth_h(rec_b, name, pc.frame[real], pc.target_id[real])
        dv = pc.doppler_mps[real] - h[:, 2]
        assert np.percentile(np.abs(dv), 95) > 1.0
        assert np.abs(dv).max() < 4.5
        # Range within the body's extent (1 m) of the torso.
        dr = pc.range_m[real] - h[:, 0]
        assert np.abs(dr).max() < 1.0
        assert np.all(pc.snr_db[fa] > PointCloudModel().threshold_db - 1e-9)
        assert np.all(np.abs(pc.doppler_mps) <= TABLE_I.max_doppler_mps)


def test_seeded_and_levels_independent(rec_b):
    again = simulate_recording("B", "random", CLEAN, levels=("centroids",), seed=11)
    assert_array_equal(again.nodes["S2"].centroids.range_m, rec_b.nodes["S2"].centroids.range_m)
    other = simulate_recording("B", "random", CLEAN, levels=("centroids",), seed=12)
    assert not np.array_equal(other.truth.state, rec_b.truth.state)


def test_multiple_targets_are_labelled():
    rec = simulate_recording("A", "random", SimulationOptions(physics=None, n_targets=3),
                             levels=("centroids", "point_cloud"), n_frames=50, seed=4)
    assert sorted(set(rec.truth.target_id.tolist())) == [0, 1, 2]
    assert rec.truth.state.shape == (150, 4)
    for name in rec.node_names:
        c = rec.nodes[name].centroids
        assert sorted(set(c.target_id.tolist())) == [0, 1, 2]
        h = _truth_h(rec, name, c.frame, c.target_id)
        assert np.abs(c.range_m - h[:, 0]).max() < 5 * CENTROID_NOISE.range_m
        assert set(rec.nodes[name].point_cloud.target_id.tolist()) == {-1, 0, 1, 2}


def test_any_network_by_poses():
    poses = {"S1": [0, 0, 0], "S2": [6, 0, 0.0], "S3": [3, 8, np.pi]}
    rec = simulate_recording(poses, "random", SimulationOptions(physics=None, known_poses=True),
                             levels=("centroids",), n_frames=40, seed=5)
    assert rec.node_names == ["S1", "S2", "S3"]
    assert_allclose(rec.nodes["S3"].pose, [3, 8, np.pi])
    assert all(len(rec.nodes[n].centroids) == 40 for n in rec.node_names)


def test_cube_level_puts_the_torso_at_its_range_and_angle():
    rec = simulate_recording("B", "straight",
                             SimulationOptions(physics=None, cube_frames=[10, 20]),
                             levels=("cube",), n_frames=30, seed=6)
    radar = TABLE_I
    for name in rec.node_names:
        node = rec.nodes[name]
        assert node.cube.shape == (2, *radar.cube_shape) and node.cube.dtype == np.complex64
        assert_array_equal(node.cube_frame, [10, 20])
        for k, f in enumerate(node.cube_frame):
            cube = node.cube[k]
            # Remove the static clutter (mean over loops), then range FFT.
            moving = cube - cube.mean(axis=1, keepdims=True)
            rp = np.fft.fft(moving, axis=0)
            power = np.sum(np.abs(rp) ** 2, axis=(1, 2))
            r_peak = np.argmax(power) * radar.range_resolution_m
            h = _truth_h(rec, name, np.array([f]), np.array([0]))[0]
            assert abs(r_peak - h[0]) < 0.3
            # Angle at the peak range bin, over the azimuth array.
            b = int(round(h[0] / radar.range_resolution_m))
            snap = rp[b - 2:b + 3][:, :, list(radar.azimuth_channels)]
            spec = np.sum(np.abs(np.fft.fftshift(np.fft.fft(snap, 256, axis=2), axes=2)) ** 2,
                          axis=(0, 1))
            omega = (np.argmax(spec) - 128) * 2 * np.pi / 256
            assert abs(wrap_angle(omega - h[1])) < 0.35


def test_simulated_recording_round_trips(tmp_path):
    rec = simulate_recording("C", "straight", SimulationOptions(physics=None, cube_frames=2),
                             n_frames=20, seed=3)
    back = read_recording(write_recording(tmp_path / "s.h5", rec))
    assert_array_equal(back.nodes["S2"].cube, rec.nodes["S2"].cube)
    assert_array_equal(back.nodes["S1"].point_cloud.doppler_mps,
                       rec.nodes["S1"].point_cloud.doppler_mps)
    assert_array_equal(back.truth.state, rec.truth.state)
    assert back.metadata == rec.metadata


def test_simulator_argument_errors():
    with pytest.raises(ValidationError, match="levels="):
        simulate_recording("C", options=CLEAN, levels=("cubes",), n_frames=5)
    with pytest.raises(ValidationError, match="cube_frames=9"):
        simulate_recording("C", options=SimulationOptions(physics=None, cube_frames=9),
                           levels=("cube",), n_frames=5)
    with pytest.raises(ValidationError, match="trajectory='loop'"):
        simulate_recording("C", "loop", CLEAN, levels=("centroids",), n_frames=5)
    with pytest.raises(ValidationError, match="trajectory states must have shape"):
        simulate_recording("C", np.zeros((5, 3)), CLEAN, levels=("centroids",))
    with pytest.raises(ConfigurationError, match="radar must be a RadarConfig"):
        simulate_recording("C", options=SimulationOptions(physics=None, radar={"n_loops": 3}),
                           levels=("centroids",), n_frames=5)
    with pytest.raises(ValidationError, match="n_targets=0"):
        simulate_recording("C", options=SimulationOptions(physics=None, n_targets=0),
                           levels=("centroids",), n_frames=5)
    with pytest.raises(ValidationError, match="centroid_p_miss=1.0"):
        simulate_recording("C", options=SimulationOptions(physics=None, centroid_p_miss=1.0),
                           levels=("centroids",), n_frames=5)
    with pytest.raises(ConfigurationError, match="centroid_noise must be a MeasurementNoise"):
        simulate_recording("C",
                           options=SimulationOptions(physics=None, centroid_noise=(0.1, 0.1, 0.1)),
                           levels=("centroids",), n_frames=5)


def test_point_cloud_noise_matches_its_stated_model():
    """A point-like body (torso points at the centre, no limbs): one detection
    per frame whose error has variance bin^2/12 + resolution^2/(2 SNR)."""
    from mmsnap_graph.sim import HumanBody

    point = HumanBody(torso_half_width_m=1e-6, torso_half_depth_m=1e-6, arm_amplitude=0.0,
                      leg_amplitude=0.0, torso_rcs_m2=0.02)
    model = PointCloudModel(false_alarms_per_frame=0.0)
    rec = simulate_recording("C", "random",
                             SimulationOptions(physics=None, body=point, point_cloud_model=model),
                             levels=("point_cloud",), seed=8)
    radar = TABLE_I
    bins = np.array([radar.range_resolution_m, 2 * np.pi / model.angle_fft_size,
                     radar.doppler_resolution_mps])
    res = np.array([radar.range_resolution_m, radar.omega_resolution_rad,
                    radar.doppler_resolution_mps])
    for name in rec.node_names:
        pc = rec.nodes[name].point_cloud
        assert np.all(np.bincount(pc.frame) <= 1) and len(pc) > 500
        h = _truth_h(rec, name, pc.frame, pc.target_id)
        e = pc.measurements - h
        e[:, 1] = wrap_angle(e[:, 1])
        # The true SNR from the measured one (1 dB noise) is close enough here.
        snr_lin = 10 ** (pc.snr_db / 10)
        sigma = np.sqrt(bins ** 2 / 12 + res ** 2 / (2 * snr_lin[:, None]))
        z2 = ((e / sigma) ** 2).mean(axis=0)
        assert_allclose(z2, 1.0, atol=0.2)
