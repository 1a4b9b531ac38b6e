"""The stream's single-frame solver (mmsnap_graph.fusion.solvers.scalar) against
GTSAM's fuse_frame: same statuses, states and covariances to the stated
tolerances, on random frames of several networks (MAP and ML, missed nodes,
per-node noise, uncertain poses)."""

from __future__ import annotations

import numpy as np
import pytest

from _shared import PAPER_NOISE, PAPER_PRIOR, POSES_A, POSES_BC, POSES_C
from factors.models import predict_measurements, wrap_angle
from mmsnap_graph import MeasurementNoise, fuse_frame
from mmsnap_graph.data.results import DEGENERACY_THRESHOLD, Status
from mmsnap_graph.fusion.solvers.scalar import COVARIANCE_TOLERANCE, STATE_TOLERANCE, FrameSolver
from mmsnap_graph.fusion.problem import check_pose_covariances

#: Four nodes around a 7 m square, each facing the centre (the stream benchmark's).
SQUARE = np.array([[0.0, 0.0, 0.0], [0.0, 7.0, np.pi], [-3.5, 3.5, -np.pi / 2], [3.5, 3.5, np.pi / 2]])
NOISES = (PAPER_NOISE, MeasurementNoise(range_m=0.05, omega_rad=0.5, doppler_mps=0.15),
          MeasurementNoise(range_m=0.03, omega_rad=0.9, doppler_mps=0.2))
POSE_COV = np.stack([np.full((3, 3), np.nan), np.diag([0.03, 0.03, 0.02]) ** 2,
                     np.diag([0.02, 0.04, 0.01]) ** 2])


def _frame(rng, poses, noises, p_miss):
    """One target in the network's area, measured with each node's sigmas."""
    lo, hi = poses[:, :2].min(axis=0), poses[:, :2].max(axis=0)
    centre = 0.5 * (lo + hi)
    half = np.maximum(0.5 * (hi - lo), 1.5)
    state = np.concatenate([centre + rng.uniform(-0.8, 0.8, 2) * half, rng.normal(0.0, 0.7, 2)])
    sig = np.array([m.sigmas for m in noises])
    z = np.stack([predict_measurements(state, p) for p in poses]) + rng.normal(size=(len(poses), 3)) * sig
    z[:, 1] = wrap_angle(z[:, 1])
    obs = rng.random(len(poses)) >= p_miss
    if not obs.any():
        obs[rng.integers(len(poses))] = True
    return z, obs


def _compare(poses, noises, prior, n_frames, seed, p_miss=0.25, pose_cov=None):
    """Both solvers on random frames: the largest state difference in sigmas,
    the largest covariance difference relative to sigma_i sigma_j, the
    status counts."""
    rng = np.random.default_rng(seed)
    solver = FrameSolver(poses, noises, prior, check_pose_covariances(pose_cov, len(poses)))
    worst_state = worst_cov = 0.0
    statuses = []
    for _ in range(n_frames):
        z, obs = _frame(rng, poses, noises, p_miss)
        ref = fuse_frame(poses, z, observed=obs, noise=list(noises), prior=prior,
                         pose_covariances=pose_cov)
        sol = solver.solve(z, obs)
        assert sol.status == int(ref.status), (z, obs, ref.message)
        statuses.append(sol.status)
        if sol.status != Status.OK:
            assert np.isnan(sol.covariance).all()
            continue
        sig = np.sqrt(np.diag(ref.covariance))
        worst_state = max(worst_state, float(np.max(np.abs(np.array(sol.state) - ref.state) / sig)))
        worst_cov = max(worst_cov, float(np.max(np.abs(sol.covariance - ref.covariance)
                                                / np.outer(sig, sig))))
        # The condition number of nearly parallel lines of sight is as sensitive
        # as its size: equal to 1e-6 where it matters (below the flag's threshold).
        if ref.degeneracy < DEGENERACY_THRESHOLD:
            assert sol.degeneracy == pytest.approx(ref.degeneracy, rel=1e-6)
        else:
            assert sol.degeneracy > 0.9 * DEGENERACY_THRESHOLD
        np.testing.assert_array_equal(sol.covariance, sol.covariance.T)
    return worst_state, worst_cov, np.bincount(statuses, minlength=4)


CASES = [
    ("square MAP", SQUARE, (PAPER_NOISE,) * 4, PAPER_PRIOR, None),
    ("square ML", SQUARE, (PAPER_NOISE,) * 4, None, None),
    ("B+C per-node noise MAP", POSES_BC, NOISES, PAPER_PRIOR, None),
    ("B+C per-node noise ML", POSES_BC, NOISES, None, None),
    ("B+C uncertain poses MAP", POSES_BC, NOISES, PAPER_PRIOR, POSE_COV),
    ("A two nodes MAP", POSES_A, (PAPER_NOISE,) * 2, PAPER_PRIOR, None),
    ("C degenerate MAP", POSES_C, (PAPER_NOISE,) * 2, PAPER_PRIOR, None),
]


@pytest.mark.parametrize("label, poses, noises, prior, pose_cov", CASES, ids=[c[0] for c in CASES])
def test_frame_solver_equals_fuse_frame(label, poses, noises, prior, pose_cov):
    worst_state, worst_cov, counts = _compare(np.asarray(poses), noises, prior, 60, seed=len(label),
                                              pose_cov=pose_cov)
    assert counts[Status.OK] >= 20  # the comparison has successes to compare
    assert worst_state <= STATE_TOLERANCE, worst_state
    assert worst_cov <= COVARIANCE_TOLERANCE, worst_cov


def test_ml_single_node_groups_are_singular_as_in_fuse_frame():
    """ML, one node: three measurements for four unknowns; both solvers say SINGULAR."""
    _, _, counts = _compare(SQUARE, (PAPER_NOISE,) * 4, None, 40, seed=7, p_miss=0.8)
    assert counts[Status.SINGULAR] >= 5 and counts[Status.OK] >= 1


def test_an_initial_position_on_a_node_is_flagged_not_raised():
    solver = FrameSolver(POSES_A, (PAPER_NOISE,) * 2, PAPER_PRIOR)
    z = np.zeros((2, 3))  # range 0 at node 0: the average detection on the node
    obs = np.array([True, False])
    sol = solver.solve(z, obs)
    assert sol.status == Status.NON_FINITE and np.isnan(sol.state).all()
    assert np.isnan(sol.covariance).all()


def test_a_prior_alone_gives_the_prior():
    solver = FrameSolver(SQUARE, (PAPER_NOISE,) * 4, PAPER_PRIOR)
    sol = solver.solve(np.zeros((4, 3)), np.zeros(4, dtype=bool))
    assert sol.status == Status.OK
    np.testing.assert_allclose(sol.state, PAPER_PRIOR.mean, atol=1e-12)
    np.testing.assert_allclose(sol.covariance, np.diag(PAPER_PRIOR.sigmas**2), rtol=1e-12)
