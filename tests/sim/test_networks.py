"""Networks, trajectories and the body model of the simulator."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose

from mmsnap_graph import GeometryError, ValidationError
from mmsnap_graph.sim.body import ARM, LEG, TORSO, HumanBody, body_scatterers
from mmsnap_graph.sim.networks import (
    COMMON_AREAS,
    CONFIGURATIONS,
    DEFAULT_FOV_RAD,
    Area,
    common_area,
    in_common_field_of_view,
    in_field_of_view,
    network_poses,
)
from mmsnap_graph.sim.trajectories import make_trajectory, random_walk, straight_line


def test_configurations_match_the_brief():
    assert_allclose(CONFIGURATIONS["C"]["S2"], [0.0, 7.0, np.pi])
    assert_allclose(CONFIGURATIONS["B"]["S2"], [5.0, 5.0, np.pi / 2])
    assert_allclose(CONFIGURATIONS["A"]["S2"], [4.0, 0.0, np.pi / 6])
    for poses in CONFIGURATIONS.values():
        assert list(poses) == ["S1", "S2"]
        assert_allclose(poses["S1"], 0.0)
    # C: the radars face each other (S2's broadside (-sin phi, cos phi) = -y).
    phi = CONFIGURATIONS["C"]["S2"][2]
    assert_allclose([-np.sin(phi), np.cos(phi)], [0, -1], atol=1e-12)


@pytest.mark.parametrize("name", ["A", "B", "C"])
def test_common_areas_are_in_every_field_of_view(name):
    area = COMMON_AREAS[name]
    gx, gy = np.meshgrid(np.linspace(area.x_min_m, area.x_max_m, 21),
                         np.linspace(area.y_min_m, area.y_max_m, 21))
    pts = np.stack([gx, gy], axis=-1)
    assert in_common_field_of_view(pts, network_poses(name)).all()


def test_field_of_view_limits():
    pose = np.array([1.0, 1.0, np.pi / 2])  # broadside along -x
    inside = [1.0 - 3.0, 1.0]
    edge_in = [1.0 - 3 * np.cos(DEFAULT_FOV_RAD - 0.01), 1.0 + 3 * np.sin(DEFAULT_FOV_RAD - 0.01)]
    edge_out = [1.0 - 3 * np.cos(DEFAULT_FOV_RAD + 0.01), 1.0 + 3 * np.sin(DEFAULT_FOV_RAD + 0.01)]
    behind = [3.0, 1.0]
    far = [1.0 - 20.0, 1.0]
    near = [1.0 - 0.2, 1.0]
    got = in_field_of_view(np.array([inside, edge_in, edge_out, behind, far, near]), pose)
    assert got.tolist() == [True, True, False, False, False, False]


def test_common_area_of_any_network():
    poses = {"S1": [0, 0, 0], "S2": [6, 0, 0.0], "S3": [3, 8, np.pi]}
    area = common_area(poses)
    assert in_common_field_of_view(area.corners_m, network_poses(poses)).all()
    assert np.all(area.size_m > 1.0)
    with pytest.raises(GeometryError, match="no common field of view"):
        common_area({"S1": [0, 0, 0], "S2": [0, -5, np.pi]})
    with pytest.raises(ValidationError, match="configuration='D'"):
        network_poses("D")
    with pytest.raises(ValidationError, match="pose of S2 must have shape"):
        network_poses({"S1": [0, 0, 0], "S2": [1, 2]})
    with pytest.raises(ValidationError, match="x_max_m > x_min_m"):
        Area(x_min_m=1, x_max_m=0, y_min_m=0, y_max_m=1)


def _check_walk(states, area, frame_period_s):
    assert area.contains(states[:, :2]).all()
    # Velocity is the derivative of the position (trapezoid over one frame).
    chord = np.diff(states[:, :2], axis=0) / frame_period_s
    mean_v = 0.5 * (states[1:, 2:] + states[:-1, 2:])
    assert np.max(np.linalg.norm(chord - mean_v, axis=1)) < 0.15


@pytest.mark.parametrize("name", ["A", "B", "C"])
def test_random_walk_stays_inside_at_human_speed(name):
    area = COMMON_AREAS[name]
    s = random_walk(area, seed=3)
    assert s.shape == (600, 4)
    _check_walk(s, area, 0.15)
    speed = np.hypot(s[:, 2], s[:, 3])
    assert speed.min() >= 0.5 - 1e-9 and speed.max() <= 1.5 + 1e-9
    assert 0.8 < speed.mean() < 1.2
    # It explores the area rather than circling in one spot.
    assert np.ptp(s[:, 0]) > 0.5 * area.size_m[0] and np.ptp(s[:, 1]) > 0.5 * area.size_m[1]
    assert_allclose(random_walk(area, seed=3), s)  # seeded


def test_straight_line_paces_back_and_forth():
    area = COMMON_AREAS["C"]
    s = straight_line(area, start_m=[-1, 3], end_m=[1, 3], speed_mps=1.2)
    _check_walk(s, area, 0.15)
    assert_allclose(s[:, 1], 3.0)
    assert_allclose(s[:, 3], 0.0)
    assert s[:, 0].min() >= -1 - 1e-9 and s[:, 0].max() <= 1 + 1e-9
    assert np.abs(s[:, 2]).max() == pytest.approx(1.2)
    # 90 s over a 2 m segment at 1.2 m/s with turns: about 40 reversals.
    reversals = np.sum(np.diff(np.sign(s[np.abs(s[:, 2]) > 0.1, 2])) != 0)
    assert 30 <= reversals <= 50
    with pytest.raises(ValidationError, match="speed_mps=5"):
        straight_line(area, speed_mps=5)
    with pytest.raises(ValidationError, match="kind='zigzag'"):
        make_trajectory("zigzag", area)
    with pytest.raises(ValidationError, match="n_frames=0"):
        random_walk(area, n_frames=0)


def test_body_torso_centroid_and_limb_doppler_spread():
    area = COMMON_AREAS["B"]
    s = random_walk(area, seed=0)
    b = body_scatterers(s, 0.15, rng=np.random.default_rng(0))
    part = b.part
    assert b.positions_m.shape == (600, HumanBody().n_scatterers, 2)
    assert set(part.tolist()) == {TORSO, ARM, LEG}
    # Truth tracks the torso: its points are centred on the state.
    assert_allclose(b.positions_m[:, part == TORSO].mean(axis=1), s[:, :2], atol=1e-12)
    rel = np.linalg.norm(b.velocities_mps - s[:, None, 2:], axis=-1)
    # Feet swing up to 2-3 times walking speed; arms less; the torso barely
    # (it only turns).
    assert 1.5 < rel[:, part == LEG].max() < 4.0
    assert 0.5 < rel[:, part == ARM].max() < rel[:, part == LEG].max()
    # (Torso points are at most 0.18 m from the centre; turns reach ~5 rad/s.)
    assert rel[:, part == TORSO].max() < 1.0
    assert np.median(rel[:, part == TORSO]) < 0.3
    # Limbs stay within reach of the torso.
    reach = np.linalg.norm(b.positions_m - s[:, None, :2], axis=-1)
    assert reach.max() < 0.9
    # Torso carries most of the RCS.
    assert b.rcs_m2[part == TORSO].sum() == pytest.approx(HumanBody().torso_rcs_m2)


def test_body_velocities_are_derivatives_of_positions():
    s = random_walk(COMMON_AREAS["B"], frame_period_s=0.002, n_frames=3000, seed=1, substeps=1)
    b = body_scatterers(s, 0.002)
    fd = (b.positions_m[2:] - b.positions_m[:-2]) / 0.004
    assert np.abs(fd - b.velocities_mps[1:-1]).max() < 0.05


def test_standing_body_has_still_limbs():
    s = np.tile([1.0, 3.0, 0.0, 0.0], (20, 1))
    b = body_scatterers(s, 0.15, rng=np.random.default_rng(2))
    assert_allclose(b.velocities_mps, 0.0, atol=1e-12)
    assert_allclose(b.positions_m, np.broadcast_to(b.positions_m[0], b.positions_m.shape), atol=1e-12)
    with pytest.raises(ValidationError, match=r"states must have shape \(F, 4\)"):
        body_scatterers(np.zeros((3, 2)), 0.15)
    with pytest.raises(ValidationError, match="n_torso=3"):
        HumanBody(n_torso=3)
