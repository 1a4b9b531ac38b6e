"""The pre-solve's range offset unknown (``PresolveProblem.range_offset``):
its gradient and Hessian against finite differences of the cost, and its
recovery on a synthetic three-node walk."""

from __future__ import annotations

import numpy as np
import pytest

from factors.models import measurement_model
from mmsnap_graph.calibration.joint.presolve import (
    RANGE_OFFSET,
    PresolveProblem,
    _problem,
    presolve,
)

SIGMAS = np.array([0.03, 0.05, 0.1])


def _scene(seed=0, n=60, depth=0.07):
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.15
    states = np.column_stack([1.5 * np.sin(0.3 * t), 3.5 + np.cos(0.4 * t),
                              0.45 * np.cos(0.3 * t), -0.4 * np.sin(0.4 * t)])
    poses = {"S1": np.zeros(3), "S2": np.array([4.0, 4.0, np.pi / 2]),
             "S3": np.array([0.5, 7.5, np.pi])}
    meas = {}
    for name, pose in poses.items():
        h, _ = measurement_model(states, pose)
        h[:, 0] -= depth
        meas[name] = h + rng.normal(0.0, SIGMAS, (n, 3))
    return poses, states, meas


def _problem_for(meas, names, prior=(0.1, 0.05)):
    return PresolveProblem(measurements=meas, names=names, reference="S1", sigmas=SIGMAS,
                           prior_sigmas=np.array([1e3, 1e3, 3.5, 3.5]),
                           motion=(np.arange(59), np.full(59, 0.15), 2.0), range_offset=prior)


@pytest.mark.parametrize("timed", [False, True])
def test_range_offset_gradient_and_hessian_match_finite_differences(timed):
    poses, states, meas = _scene()
    offsets = {RANGE_OFFSET: 0.06, **({"S2": 0.01, "S3": -0.02} if timed else {})}
    prob, p, s, o = _problem(_problem_for(meas, list(poses)), poses, states, offsets)
    hess, grad = prob.system(p, s, o)
    col = prob.s0 + prob.dcol
    eps = 1e-6
    up, down = {**o, RANGE_OFFSET: o[RANGE_OFFSET] + eps}, {**o, RANGE_OFFSET: o[RANGE_OFFSET] - eps}
    numeric = (prob.cost(p, s, up) - prob.cost(p, s, down)) / (2 * eps)
    assert grad[col] == pytest.approx(numeric, rel=1e-6)
    numeric_col = (prob.system(p, s, up)[1] - prob.system(p, s, down)[1]) / (2 * eps)
    np.testing.assert_allclose(hess[:, col].toarray().ravel(), numeric_col,
                               atol=1e-6 * np.abs(numeric_col).max())


def test_presolve_recovers_the_range_offset():
    """True depth 0.07 m, prior 0.10 +- 0.05 m: within 2 sigma of the data."""
    poses, states, meas = _scene()
    problem = _problem_for(meas, list(poses))
    p, s, o = presolve(problem, poses, states, offsets={RANGE_OFFSET: 0.1})
    assert o == {RANGE_OFFSET: pytest.approx(o[RANGE_OFFSET])}  # not timed: the offset only
    assert abs(o[RANGE_OFFSET] - 0.07) < 0.02
    without = PresolveProblem(measurements=meas, names=list(poses), reference="S1",
                              sigmas=SIGMAS, prior_sigmas=np.array([1e3, 1e3, 3.5, 3.5]),
                              motion=problem.motion)
    p0, _ = presolve(without, poses, states)
    # S3 faces S1 across 7.5 m: without the offset their baseline shrinks by ~2 d.
    assert np.linalg.norm(p0["S3"][:2]) < np.linalg.norm(poses["S3"][:2]) - 0.08
    assert abs(np.linalg.norm(p["S3"][:2]) - np.linalg.norm(poses["S3"][:2])) < 0.04
