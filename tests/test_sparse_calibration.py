"""Sparse point clouds on the default path (issue 14, Build 7): the
clustering adapts to clouds of 2-3 points per frame, and the multi-target
refinement alternates association and joint solve."""

import dataclasses

import numpy as np
import pytest

from mmsnap_graph.app.pipeline import (
    SPARSE_POINTS_PER_FRAME,
    cluster_node,
    process_recording,
    sparse_cluster_config,
)
from mmsnap_graph.calibration import calibrate_recording, pose_tangent_error
from mmsnap_graph.calibration.joint.multi_refine import refine_multi
from mmsnap_graph.errors import ValidationError
from mmsnap_graph.radar.chain import ChainConfig
from mmsnap_graph.sim import simulate_recording
from mmsnap_graph.sim.sparse import sparse_clouds
from mmsnap_graph.sim import SimulationOptions

NETWORK = {"S1": (0.0, 0.0, 0.0), "S2": (0.0, 7.0, np.pi), "S3": (4.0, 0.0, np.pi / 6)}


@pytest.fixture(scope="module")
def dense():
    return simulate_recording(NETWORK, "random",
                              SimulationOptions(physics=None, n_targets=2, frame_period_s=0.05),
                              levels=("point_cloud",), n_frames=120, seed=4)


def test_sparse_clouds_are_clustered_with_one_point_minimum(dense):
    sparse = sparse_clouds(dense, seed=4)
    cfg = ChainConfig()
    same, changed = sparse_cluster_config(dense.nodes["S1"].point_cloud, cfg)
    assert same is cfg and not changed                         # ~35 points per frame
    thin, changed = sparse_cluster_config(sparse.nodes["S1"].point_cloud, cfg)
    assert changed and thin.cluster.min_samples == 1
    assert thin.cluster.eps_m == cfg.cluster.eps_m             # the rest kept
    kept, changed = sparse_cluster_config(sparse.nodes["S1"].point_cloud, cfg, sparse=False)
    assert kept is cfg and not changed
    forced, changed = sparse_cluster_config(dense.nodes["S1"].point_cloud, cfg, sparse=True)
    assert changed and forced.cluster.min_samples == 1
    counts = np.bincount(sparse.nodes["S1"].point_cloud.frame)
    assert np.median(counts[counts > 0]) < SPARSE_POINTS_PER_FRAME


def test_sparse_node_gets_a_centroid_in_most_non_empty_frames(dense):
    node = sparse_clouds(dense, seed=4).nodes["S2"]
    auto, rep = cluster_node(node, dense.frame_period_s)
    off, _ = cluster_node(node, dense.frame_period_s, sparse=False)
    full = np.unique(node.point_cloud.frame).size
    assert np.unique(auto.centroids.frame).size > 0.9 * full
    assert np.unique(off.centroids.frame).size < 0.5 * full     # DBSCAN's 3-point minimum
    assert "sparse cloud" in rep.message


def test_refine_multi_checks_its_rounds(dense):
    proc = process_recording(dense)[0]
    pg = calibrate_recording(proc, method="pose_graph").pose_graph
    with pytest.raises(ValidationError, match="n_rounds"):
        refine_multi(proc, pg, n_rounds=0)


@pytest.mark.slow
def test_more_rounds_do_not_move_a_converged_calibration(dense):
    """Rounds stop when the poses stop moving; one round is the old path."""
    meta = {k: v for k, v in dense.metadata.items() if not k.startswith("centroid_")}
    proc = dataclasses.replace(process_recording(dense)[0], metadata=meta)
    pg = calibrate_recording(proc, method="pose_graph").pose_graph
    one = refine_multi(proc, pg, n_rounds=1)
    three = refine_multi(proc, pg, n_rounds=3)
    assert one.joint.success and three.joint.success
    for n in ("S2", "S3"):
        assert np.hypot(*(three.joint.poses[n][:2] - one.joint.poses[n][:2])) < 0.05


def _default_path_error(rec):
    """Mean position error of S2 and S3 on the default path (``mmsnap
    process`` then ``mmsnap calibrate``), without the simulator's noise
    metadata (a real recording has none)."""
    meta = {k: v for k, v in rec.metadata.items() if not k.startswith("centroid_")}
    proc = dataclasses.replace(process_recording(rec)[0], metadata=meta)
    cal = calibrate_recording(proc)
    assert cal.success and cal.method == "joint"
    return float(np.mean([np.hypot(*pose_tangent_error(cal.poses[n], rec.truth.node_poses[n])[:2])
                          for n in ("S2", "S3")]))


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason=(
    "issue 14 target (1.2x the dense error) not reachable on these data by any estimator: the "
    "Cramer-Rao bound of the S2/S3 positions from the chain's centroids "
    "(evaluation.pose_bound, tests/evaluation/test_pose_bound.py) is, on seed 0, sparse 47 mm against "
    "dense 17 mm (2.8x; 26 against 10 mm, 2.5x, with the trajectory known), 2.5-4.7x on "
    "seeds 0-7: sparse centroids are single body points, 0.14-0.17 m range / 0.09-0.14 rad "
    "omega / 0.4-0.7 m/s Doppler about the nodes' consensus against 0.03-0.08 m / "
    "0.03-0.12 rad / 0.06-0.15 m/s dense. Measured seed 0: dense 7.0 mm, sparse 42 mm (6.0x; "
    "S3 72 mm, 1.7 of its reported 42 mm sigma); seed 1 0.72x (sparse 5.7 mm, 0.2 of its "
    "bound: luck), seed 2 2.8x"))
def test_sparse_clouds_within_1_2x_of_the_dense_case_seed_0():
    dense = simulate_recording(NETWORK, "random",
                               SimulationOptions(physics=None, n_targets=2, frame_period_s=0.05),
                               levels=("point_cloud",), n_frames=600, seed=0)
    assert _default_path_error(sparse_clouds(dense, seed=0)) <= 1.2 * _default_path_error(dense)
