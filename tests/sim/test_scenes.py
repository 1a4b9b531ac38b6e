"""Small calibration scenes (mmsnap_graph.sim.scenes): the target's smooth
trajectories, and each node's measurements of it against the geometry (range
and range rate need no frame convention)."""

from __future__ import annotations

import numpy as np
import pytest

from mmsnap_graph.data.noise import MeasurementNoise
from mmsnap_graph.errors import GeometryError, ValidationError
from mmsnap_graph.sim.scenes import (
    COMMON_AREA_CENTERS,
    PAPER_CONFIGURATIONS,
    synthetic_scene,
    target_trajectory,
)

QUIET = MeasurementNoise(range_m=1e-9, omega_rad=1e-9, doppler_mps=1e-9)


@pytest.mark.parametrize("kind", ["random", "straight"])
def test_the_velocity_is_the_derivative_of_the_position(kind):
    dt = 0.01
    x = target_trajectory(2001, [0.0, 5.0], frame_period_s=dt, kind=kind,
                          rng=np.random.default_rng(2))
    central = (x[2:, :2] - x[:-2, :2]) / (2 * dt)
    np.testing.assert_allclose(x[1:-1, 2:], central, atol=1e-4)   # O(dt^2 |x'''|)
    speed = np.hypot(x[:, 2], x[:, 3])
    assert 0.05 < np.median(speed) < 1.5                      # a walking person


def test_straight_walks_on_one_line_through_the_centre_and_standing_stays():
    c = np.array([1.0, 4.0])
    x = target_trajectory(400, c, kind="straight", rng=np.random.default_rng(0))
    d = x[:, :2] - c
    far = d[np.argmax(np.hypot(d[:, 0], d[:, 1]))]          # the line's direction
    np.testing.assert_allclose(d[:, 0] * far[1] - d[:, 1] * far[0], 0.0, atol=1e-9)
    still = target_trajectory(10, c, kind="standing", rng=np.random.default_rng(0))
    np.testing.assert_array_equal(still, np.tile([1.0, 4.0, 0.0, 0.0], (10, 1)))
    with pytest.raises(ValidationError, match="kind='zigzag'"):
        target_trajectory(10, c, kind="zigzag", rng=np.random.default_rng(0))


def test_measurements_are_the_ranges_and_range_rates_of_the_geometry():
    poses = PAPER_CONFIGURATIONS["C"]
    scene = synthetic_scene(poses, n_frames=200, noise=QUIET, center_m=COMMON_AREA_CENTERS["C"],
                            rng=np.random.default_rng(5))
    assert scene.frame.tolist() == list(range(200)) and scene.truth.shape == (200, 4)
    for name, pose in poses.items():
        d = scene.truth[:, :2] - pose[:2]
        r = np.hypot(d[:, 0], d[:, 1])
        z = scene.measurements[name]
        np.testing.assert_allclose(z[:, 0], r, atol=1e-6)
        np.testing.assert_allclose(z[:, 2], np.sum(d * scene.truth[:, 2:], axis=1) / r,
                                   atol=1e-6)
        assert np.all(np.abs(z[:, 1]) < np.pi)
        # the local points are the detections: as far from the node as measured
        np.testing.assert_allclose(np.hypot(*scene.local_points_m[name].T), z[:, 0], atol=1e-9)
        assert not scene.ghost[name].any()


def test_ghosts_replace_about_the_fraction_asked_and_leave_the_rest():
    poses = PAPER_CONFIGURATIONS["B"]
    scene = synthetic_scene(poses, n_frames=1000, noise=QUIET, ghost_fraction=0.2,
                            rng=np.random.default_rng(9))
    for name, pose in poses.items():
        g = scene.ghost[name]
        # binomial(1000, 0.2): sd 12.6, so 4 sd either side
        assert 150 < g.sum() < 250
        r = np.hypot(*(scene.truth[:, :2] - pose[:2]).T)
        np.testing.assert_allclose(scene.measurements[name][~g, 0], r[~g], atol=1e-6)
        assert np.all((scene.measurements[name][g, 0] >= 1.0)
                      & (scene.measurements[name][g, 0] <= 10.0))


def test_the_same_generator_state_gives_the_same_scene():
    c = COMMON_AREA_CENTERS["A"]
    a = synthetic_scene(PAPER_CONFIGURATIONS["A"], n_frames=50, center_m=c,
                        rng=np.random.default_rng(3))
    b = synthetic_scene(PAPER_CONFIGURATIONS["A"], n_frames=50, center_m=c,
                        rng=np.random.default_rng(3))
    np.testing.assert_array_equal(a.truth, b.truth)
    for name in a.measurements:
        np.testing.assert_array_equal(a.measurements[name], b.measurements[name])


def test_a_target_behind_or_too_close_to_a_node_is_a_geometry_error():
    poses = {"S1": np.zeros(3), "S2": np.array([0.0, 7.0, np.pi])}
    with pytest.raises(GeometryError, match="half plane"):
        synthetic_scene(poses, n_frames=20, center_m=[0.0, -3.0], kind="standing",
                        rng=np.random.default_rng(0))
    with pytest.raises(GeometryError, match="comes within 0.50 m of node S1"):
        synthetic_scene(poses, n_frames=20, center_m=[0.0, 0.5], kind="standing",
                        rng=np.random.default_rng(0))
    with pytest.raises(ValidationError, match="noise must be a MeasurementNoise"):
        synthetic_scene(poses, noise=(0.1, 0.1, 0.1), rng=np.random.default_rng(0))
