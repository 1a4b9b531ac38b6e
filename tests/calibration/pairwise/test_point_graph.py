"""Every node's pose at once from the matched points of all node pairs
(mmsnap_graph.calibration.pairwise.point_graph): noise-free points give the
true poses, and with two nodes the solve is the closed form (a different
solver: the SVD of the points' cross-covariance)."""

from __future__ import annotations

import numpy as np
import pytest

from factors.models import global_to_local
from mmsnap_graph.calibration import closed_form_calibration, pose_tangent_error
from mmsnap_graph.calibration.pairwise.point_graph import PointEdge, solve_point_graph

from _shared import NETWORK_3


def _walk(rng, n=200):
    return np.array([1.0, 4.0]) + rng.uniform(-1.5, 1.5, size=(n, 2))


def _edge(a, b, xy, noise=0.0, rng=None):
    za, zb = (global_to_local(xy, NETWORK_3[n]) for n in (a, b))
    if noise:
        za = za + noise * rng.normal(size=za.shape)
        zb = zb + noise * rng.normal(size=zb.shape)
    return PointEdge(node_a=a, node_b=b, points_a_m=za, points_b_m=zb,
                     times=0.15 * np.arange(len(xy)))


def test_noise_free_points_of_three_pairs_give_the_true_poses():
    rng = np.random.default_rng(0)
    xy = _walk(rng)
    edges = [_edge("S1", "S2", xy), _edge("S1", "S3", xy), _edge("S2", "S3", xy)]
    start = {"S1": np.zeros(3), "S2": NETWORK_3["S2"] + [0.4, -0.3, 0.15],
             "S3": NETWORK_3["S3"] + [-0.2, 0.3, -0.1]}
    sol = solve_point_graph("S1", start, edges, autocorrelation=False)
    assert sol.converged and sol.order == ("S2", "S3")
    for n in ("S2", "S3"):
        np.testing.assert_allclose(pose_tangent_error(sol.poses[n], NETWORK_3[n]), 0.0,
                                   atol=1e-9)
    assert sol.cost_m2 < 1e-16
    np.testing.assert_array_equal(sol.poses["S1"], np.zeros(3))
    assert sol.covariance.shape == (6, 6)


def test_two_nodes_give_the_closed_form_pose():
    rng = np.random.default_rng(1)
    xy = _walk(rng)
    edge = _edge("S1", "S2", xy, noise=0.05, rng=rng)
    cf = closed_form_calibration(edge.points_a_m, edge.points_b_m)
    sol = solve_point_graph("S1", {"S1": np.zeros(3), "S2": NETWORK_3["S2"] + [0.3, 0.3, 0.1]},
                            [edge], autocorrelation=False)
    assert sol.converged
    np.testing.assert_allclose(sol.poses["S2"], cf.pose, atol=1e-9)
    # the residual cost is the closed form's sum of squared residuals
    local = global_to_local(edge.points_a_m, cf.pose)
    assert sol.cost_m2 == pytest.approx(np.sum((local - edge.points_b_m) ** 2), rel=1e-9)


def test_points_that_cannot_fix_a_pose_raise_lin_alg_error():
    """One target standing still: the rotation about it is free."""
    xy = np.tile([[1.0, 4.0]], (50, 1))
    with pytest.raises(np.linalg.LinAlgError):
        solve_point_graph("S1", {"S1": np.zeros(3), "S2": NETWORK_3["S2"]},
                          [_edge("S1", "S2", xy)], autocorrelation=False)
