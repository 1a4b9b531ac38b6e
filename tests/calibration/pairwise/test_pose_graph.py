"""Network-wide calibration by a pose graph of pairwise estimates."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose

from mmsnap_graph.calibration import MatchingOptions
from mmsnap_graph.calibration import (
    LocalTracks,
    PoseEdge,
    pairwise_edges,
    pose_array,
    pose_tangent_error,
    pose_graph_calibration,
    to_pose2,
)
from mmsnap_graph.sim.scenes import synthetic_scene
from mmsnap_graph.errors import ValidationError

from _shared import NETWORK_BCA, TRACK_NOISE

#: S1 and the S2 of configurations B, C and A.
TRUE_POSES = NETWORK_BCA


def _edge(a, b, cov, rng, poses=TRUE_POSES, lag=0):
    rel = to_pose2(poses[a]).between(to_pose2(poses[b]))
    xi = np.linalg.cholesky(cov) @ rng.normal(size=3)
    return PoseEdge(node_a=a, node_b=b, pose=pose_array(rel.retract(xi)), covariance=cov,
                    lag_frames=lag)


def _random_cov(rng, scale=0.05):
    a = rng.normal(size=(3, 3)) * scale
    return a @ a.T + np.diag([scale**2, scale**2, (scale / 5) ** 2])


def test_a_single_edge_is_returned_unchanged():
    rng = np.random.default_rng(0)
    cov = _random_cov(rng)
    e = _edge("S1", "S2", cov, rng)
    res = pose_graph_calibration(["S1", "S2"], [e])
    assert res.success and res.unreachable == ()
    assert_allclose(res.poses["S2"], e.pose, atol=1e-9)
    assert_allclose(res.covariances["S2"], cov, rtol=1e-6, atol=1e-12)
    assert_allclose(res.poses["S1"], np.zeros(3))
    assert_allclose(res.covariances["S1"], np.zeros((3, 3)))


def test_a_reversed_edge_gives_the_inverse_pose():
    rng = np.random.default_rng(1)
    cov = _random_cov(rng)
    e = _edge("S2", "S1", cov, rng)
    res = pose_graph_calibration(["S1", "S2"], [e])
    assert_allclose(res.poses["S2"], pose_array(to_pose2(e.pose).inverse()), atol=1e-9)


def test_marginal_covariances_are_consistent_and_loops_help():
    """4 nodes, all 6 edges with known covariances; 200 Monte Carlo trials.
    Mean NEES per node ~ chi2(3) mean, sd sqrt(6/200) = 0.17: accept 3 +- 0.55.
    The fully connected graph must beat the spanning tree S1-S2, S1-S3, S1-S4."""
    rng = np.random.default_rng(2)
    covs = {(a, b): _random_cov(rng) for a, b in
            [("S1", "S2"), ("S1", "S3"), ("S1", "S4"), ("S2", "S3"), ("S2", "S4"), ("S3", "S4")]}
    nees = {n: [] for n in ("S2", "S3", "S4")}
    names = list(TRUE_POSES)
    for _ in range(200):
        edges = [_edge(a, b, c, rng) for (a, b), c in covs.items()]
        res = pose_graph_calibration(names, edges)
        assert res.success
        for n in nees:
            e = pose_tangent_error(res.poses[n], TRUE_POSES[n])
            nees[n].append(e @ np.linalg.solve(res.covariances[n], e))
    for n, v in nees.items():
        assert abs(np.mean(v) - 3.0) < 0.55, (n, np.mean(v))
    tree = pose_graph_calibration(names, edges[:3])
    for n in nees:
        assert np.trace(res.covariances[n]) < np.trace(tree.covariances[n])
        # the spanning tree's marginals are the edges' own covariances
        assert_allclose(tree.covariances[n], covs[("S1", n)], rtol=1e-5)


def test_unreachable_nodes_are_reported_not_guessed():
    rng = np.random.default_rng(3)
    e12 = _edge("S1", "S2", _random_cov(rng), rng)
    e34 = _edge("S3", "S4", _random_cov(rng), rng)
    res = pose_graph_calibration(["S1", "S2", "S3", "S4"], [e12, e34],
                                 failures={"S1-S3": "no common frames"})
    assert not res.success
    assert res.unreachable == ("S3", "S4")
    assert set(res.poses) == {"S1", "S2"} and set(res.covariances) == {"S1", "S2"}
    assert "no path to S1: S3, S4" in res.message
    assert res.failures == {"S1-S3": "no common frames"}
    assert len(res.edges) == 1


def test_lags_compose_along_the_path():
    rng = np.random.default_rng(4)
    edges = [_edge("S1", "S2", _random_cov(rng), rng, lag=1),
             _edge("S3", "S2", _random_cov(rng), rng, lag=2)]
    res = pose_graph_calibration(["S1", "S2", "S3"], edges)
    assert res.lag_frames == {"S1": 0, "S2": 1, "S3": -1}


def test_reference_can_be_another_node():
    rng = np.random.default_rng(5)
    e = _edge("S1", "S2", _random_cov(rng), rng)
    res = pose_graph_calibration(["S1", "S2"], [e], reference="S2")
    assert_allclose(res.poses["S1"], pose_array(to_pose2(e.pose).inverse()), atol=1e-9)


def test_end_to_end_from_tracks_of_four_nodes():
    """One target in the common area of four nodes, track-like noise."""
    rng = np.random.default_rng(6)
    scene = synthetic_scene(TRUE_POSES, center_m=np.array([1.5, 3.5]), n_frames=300,
                            noise=TRACK_NOISE, extent_m=1.0, rng=rng)
    tracks = {n: LocalTracks(frame=scene.frame, points_m=scene.local_points_m[n],
                             track_id=np.zeros(300, int), source="synthetic") for n in TRUE_POSES}
    edges, failures = pairwise_edges(tracks, frame_period_s=0.1,
                                     options=MatchingOptions(max_lag_s=0.1))
    assert failures == {} and len(edges) == 6
    res = pose_graph_calibration(list(TRUE_POSES), edges, failures=failures)
    assert res.success, res.message
    for n in ("S2", "S3", "S4"):
        err = pose_tangent_error(res.poses[n], TRUE_POSES[n])
        assert np.hypot(err[0], err[1]) < 0.1 and abs(err[2]) < np.radians(1.5)
        assert res.lag_frames[n] == 0


def test_validation_errors():
    rng = np.random.default_rng(7)
    cov = _random_cov(rng)
    e = _edge("S1", "S2", cov, rng)
    with pytest.raises(ValidationError, match="edge S1-S9 names node 'S9'"):
        pose_graph_calibration(["S1", "S2"], [PoseEdge(node_a="S1", node_b="S9", pose=e.pose,
                                                      covariance=cov)])
    with pytest.raises(ValidationError, match="node_names must be unique"):
        pose_graph_calibration(["S1", "S1"], [e])
    with pytest.raises(ValidationError, match="reference='S7' is not one of the nodes"):
        pose_graph_calibration(["S1", "S2"], [e], reference="S7")
    with pytest.raises(ValidationError, match="edge S1-S2 covariance must be positive definite"):
        PoseEdge(node_a="S1", node_b="S2", pose=e.pose, covariance=np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(ValidationError, match="an edge must join two nodes, got 'S1' twice"):
        PoseEdge(node_a="S1", node_b="S1", pose=e.pose, covariance=cov)
    with pytest.raises(ValidationError, match=r"edge S1-S2 pose must have shape \(3\), got \(2,\)"):
        PoseEdge(node_a="S1", node_b="S2", pose=[1.0, 2.0], covariance=cov)
