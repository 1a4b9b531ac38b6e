"""Networks of the simulator (mmsnap_graph.sim.networks): configurations, common
areas, fields of view."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose

from mmsnap_graph import GeometryError, ValidationError
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


@pytest.mark.parametrize("n_nodes", [2, 3, 4, 5])
def test_random_networks_overlap_and_repeat_with_their_seed(n_nodes):
    from mmsnap_graph.sim.networks import random_network

    for seed in range(2):
        poses = random_network(n_nodes, seed)
        assert list(poses) == [f"S{i}" for i in range(1, n_nodes + 1)]
        assert_allclose(poses["S1"], 0.0)
        xy = np.stack([p[:2] for p in poses.values()])
        gaps = np.linalg.norm(xy[:, None] - xy[None], axis=-1)[np.triu_indices(n_nodes, 1)]
        assert np.all(gaps >= 1.5)
        area = common_area(poses)
        assert area.size_m.min() >= 1.5
        gx, gy = np.meshgrid(np.linspace(area.x_min_m, area.x_max_m, 9),
                             np.linspace(area.y_min_m, area.y_max_m, 9))
        assert in_common_field_of_view(np.stack([gx, gy], axis=-1), poses).all()
        again = random_network(n_nodes, seed)
        for name in poses:
            assert_allclose(again[name], poses[name])


def test_random_network_refuses_bad_arguments():
    from mmsnap_graph.sim.networks import random_network

    with pytest.raises(ValidationError, match="n_nodes"):
        random_network(0, 1)
    with pytest.raises(ValidationError, match="distance_m"):
        random_network(2, 1, distance_m=(5.0, 2.0))
    with pytest.raises(GeometryError, match="no network"):
        random_network(3, 1, distance_m=(14.9, 15.0), max_tries=3)
