"""What sparse clouds allow (issue 14, Build 7: "sparse within 1.2x of the
dense error"): the Cramer-Rao bound of the node poses from each case's
centroids (evaluation.pose_bound), checked against a Monte Carlo of the
least-squares estimator, and the bound ratio sparse / dense measured on
the scene of tests/sim/real/test_sparse.py."""

import dataclasses

import numpy as np
import pytest

from factors.models import measurement_model_pose, predict_measurements, wrap_angle
from mmsnap_graph.app.pipeline import process_recording
from mmsnap_graph.evaluation.pose_bound import (
    centroid_residuals,
    consensus_sigmas,
    lag1_correlation,
    pose_crb,
    residual_sigmas,
)
from mmsnap_graph.data.recording import Detections, Truth
from mmsnap_graph.errors import ValidationError
from mmsnap_graph.sim import simulate_recording
from mmsnap_graph.sim.real.sparse import sparse_clouds
from mmsnap_graph.sim import SimulationOptions

NETWORK = {"S1": (0.0, 0.0, 0.0), "S2": (0.0, 7.0, np.pi), "S3": (4.0, 0.0, np.pi / 6)}
POSES = {n: np.array(p) for n, p in NETWORK.items()}
SIGMAS = np.array([0.05, 0.05, 0.1])


def _walk(n_frames, seed):
    """Two targets on smooth walks in front of the nodes, 2.8 m apart or
    more (never mistaken for each other): a Truth."""
    rng = np.random.default_rng(seed)
    t = np.arange(n_frames) * 0.05
    rows = []
    for k, (cx, cy) in enumerate(((1.0, 2.5), (3.0, 5.0))):
        w = 0.3 + 0.1 * k
        x = cx + 0.6 * np.sin(w * t + rng.uniform(0, 6))
        y = cy + 0.6 * np.cos(0.7 * w * t + rng.uniform(0, 6))
        vx = np.gradient(x, t)
        vy = np.gradient(y, t)
        rows.append((np.arange(n_frames), np.full(n_frames, k), np.column_stack([x, y, vx, vy])))
    return Truth(frame=np.concatenate([r[0] for r in rows]),
                 target_id=np.concatenate([r[1] for r in rows]),
                 state=np.concatenate([r[2] for r in rows]), node_poses=POSES)


def _fit_pose(z, states, start):
    """Gauss-Newton of one node's pose with the states known (the estimator
    whose covariance the known-trajectory bound is)."""
    import gtsam  # function-level: GTSAM only for the retraction

    pose = gtsam.Pose2(*start)
    for _ in range(5):
        p = np.array([pose.x(), pose.y(), pose.theta()])
        h, j_pose, _ = measurement_model_pose(p, states)
        r = z - h
        r[:, 1] = wrap_angle(r[:, 1])
        a = (j_pose / SIGMAS[None, :, None]).reshape(-1, 3)
        pose = pose.retract(np.linalg.lstsq(a, (r / SIGMAS).reshape(-1), rcond=None)[0])
    return np.asarray(gtsam.Pose2(*start).localCoordinates(pose))


def test_known_trajectory_bound_is_the_least_squares_covariance():
    truth = _walk(300, 0)
    obs = {"S1": (truth.frame[:0], truth.target_id[:0], SIGMAS),
           "S3": (truth.frame, truth.target_id, SIGMAS)}
    crb = pose_crb(obs, truth, POSES, "S1", nuisance=False)["S3"]
    rng = np.random.default_rng(1)
    h = predict_measurements(truth.state, POSES["S3"])
    errs = np.array([_fit_pose(h + rng.normal(size=h.shape) * SIGMAS, truth.state, POSES["S3"])
                     for _ in range(200)])
    cov = errs.T @ errs / len(errs)
    # 200 trials: the variances within ~10% (standard error 1/sqrt(100) each).
    np.testing.assert_allclose(np.diag(cov), np.diag(crb), rtol=0.25)
    ratio = np.sqrt(np.trace(cov[:2, :2]) / np.trace(crb[:2, :2]))
    assert 0.9 < ratio < 1.1


def test_unknown_states_cost_information():
    truth = _walk(200, 2)
    obs = {n: (truth.frame, truth.target_id, SIGMAS) for n in NETWORK}
    known = pose_crb(obs, truth, POSES, "S1", nuisance=False)
    free = pose_crb(obs, truth, POSES, "S1", nuisance=True)
    for n in ("S2", "S3"):
        assert np.all(np.linalg.eigvalsh(free[n] - known[n]) > -1e-12)
        assert np.trace(free[n][:2, :2]) > 1.5 * np.trace(known[n][:2, :2])
    # Four times the sigma, half the detections: 4 / sqrt(1/2) in standard deviation.
    thin = {n: (f[::2], t[::2], 4 * s) for n, (f, t, s) in obs.items()}
    worse = pose_crb(thin, truth, POSES, "S1", nuisance=True)
    for n in ("S2", "S3"):
        assert np.sqrt(np.trace(worse[n][:2, :2]) / np.trace(free[n][:2, :2])) == \
            pytest.approx(4 * np.sqrt(2), rel=0.1)


def _detections(truth, pose, noise):
    h = predict_measurements(truth.state, pose) + noise
    return Detections(frame=truth.frame, range_m=h[:, 0], omega_rad=h[:, 1],
                      doppler_mps=h[:, 2])


def test_consensus_sigmas_leave_the_common_offset_out():
    """A body point 0.15 m off the torso seen alike by every node is no
    noise to the poses: the spread about the truth includes it, the spread
    about the nodes' consensus does not."""
    truth = _walk(600, 3)
    rng = np.random.default_rng(4)
    offset = rng.normal(size=(len(truth.frame), 2)) * 0.15
    moved = dataclasses.replace(truth, state=truth.state + np.column_stack([offset, 0 * offset]))
    res = {}
    for n, pose in POSES.items():
        det = _detections(moved, pose, rng.normal(size=(len(truth.frame), 3)) * SIGMAS)
        res[n] = centroid_residuals(det, truth, pose)
        assert res[n][0].size == len(truth.frame)                    # all within the gate
    cons = consensus_sigmas(res, truth, POSES)
    for n in NETWORK:
        assert residual_sigmas(res[n][2])[0] > 2 * SIGMAS[0]         # the offset counted
        # Per node the split of each group's few degrees of freedom (Doppler:
        # 3 measurements, 2 velocity unknowns) is loose: measured within 13%.
        np.testing.assert_allclose(cons[n], SIGMAS, rtol=0.2)
        assert np.all(np.abs(lag1_correlation(*res[n])) < 0.1)       # white
    pooled = np.sqrt(np.mean([cons[n] ** 2 for n in NETWORK], axis=0))
    np.testing.assert_allclose(pooled, SIGMAS, rtol=0.08)            # measured within 5%


def test_bound_inputs_are_checked():
    truth = _walk(20, 0)
    obs = {"S1": (truth.frame, truth.target_id, SIGMAS)}
    with pytest.raises(ValidationError, match="no node but the reference"):
        pose_crb(obs, truth, POSES, "S1")
    with pytest.raises(ValidationError, match="node_poses"):
        pose_crb({**obs, "S9": obs["S1"]}, truth, POSES, "S1")
    with pytest.raises(ValidationError, match="no truth state"):
        pose_crb({**obs, "S2": (truth.frame + 100, truth.target_id, SIGMAS)}, truth, POSES, "S1")
    with pytest.raises(ValidationError, match="singular"):
        pose_crb({**obs, "S2": (truth.frame[:1], truth.target_id[:1], SIGMAS)}, truth, POSES,
                 "S1")
    with pytest.raises(ValidationError, match="node_pose"):
        centroid_residuals(_detections(truth, POSES["S1"], 0.0), truth, np.zeros(2))
    with pytest.raises(ValidationError, match="residual"):
        residual_sigmas(np.zeros((1, 3)))


def _bound_mm(rec):
    """Mean over S2 and S3 of the position CRB (sqrt of the trace, mm) from
    the default chain's centroids, consensus sigmas; (states unknown,
    trajectory known)."""
    proc = process_recording(rec)[0]
    res = {n: centroid_residuals(node.centroids, rec.truth, rec.truth.node_poses[n])
           for n, node in proc.nodes.items()}
    sig = consensus_sigmas(res, rec.truth, rec.truth.node_poses)
    obs = {n: (f, t, sig[n]) for n, (f, t, _) in res.items()}
    out = []
    for nuisance in (True, False):
        crb = pose_crb(obs, rec.truth, rec.truth.node_poses, "S1", nuisance=nuisance)
        out.append(1e3 * np.mean([np.sqrt(np.trace(crb[n][:2, :2])) for n in ("S2", "S3")]))
    return out


@pytest.mark.slow
def test_sparse_clouds_bound_is_over_twice_the_dense_bound_seed_0():
    """The scene of the strict xfail (tests/calibration/test_network.py), seed 0:
    bound dense 17.0 mm (10.4 with the trajectory known), sparse 47.4 mm
    (26.3): 2.8x (2.5x). No estimator reaches 1.2x on these data."""
    dense = simulate_recording(NETWORK, "random",
                               SimulationOptions(physics=None, n_targets=2, frame_period_s=0.05),
                               levels=("point_cloud",), n_frames=600, seed=0)
    (d_free, d_known), (s_free, s_known) = _bound_mm(dense), _bound_mm(sparse_clouds(dense,
                                                                                      seed=0))
    assert d_free < 25 and d_known < 15                                  # 17.0, 10.4 mm
    assert s_free / d_free > 2.0 and s_known / d_known > 2.0             # 2.8x, 2.5x
