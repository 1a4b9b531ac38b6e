"""The velocity degeneracy indicator (mmsnap_graph.fusion.degeneracy): the
condition number of the lines of sight's velocity information."""

from __future__ import annotations

import numpy as np
import pytest

from _shared import POSES_C
from mmsnap_graph.fusion import degeneracy as problem
from mmsnap_graph.fusion.degeneracy import condition_2x2


def test_condition_2x2_is_the_eigenvalue_ratio():
    assert condition_2x2(2.0, 0.0, 2.0) == pytest.approx(1.0)
    a = np.array([[3.0, 1.0], [1.0, 2.0]])
    eig = np.linalg.eigvalsh(a)
    assert condition_2x2(3.0, 1.0, 2.0) == pytest.approx(eig[1] / eig[0], rel=1e-12)
    assert condition_2x2(1.0, 1.0, 1.0) == np.inf  # parallel lines of sight


def test_velocity_degeneracy_is_the_condition_number_of_the_lines_of_sight():
    rng = np.random.default_rng(11)
    states = np.column_stack([rng.uniform(-2, 2, 30), rng.uniform(1, 6, 30), np.zeros(30), np.zeros(30)])
    obs = rng.random((30, 2)) > 0.2
    got = problem.velocity_degeneracy(states, POSES_C, obs)
    for f in range(30):
        # One state gives a float, the same number.
        assert problem.velocity_degeneracy(states[f], POSES_C, obs[f]) == pytest.approx(got[f], rel=1e-12)
        u = states[f, :2] - POSES_C[obs[f], :2]
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        eig = np.linalg.eigvalsh(u.T @ u)
        want = np.inf if eig[0] <= 1e-12 * max(eig[1], 1e-300) else eig[1] / eig[0]
        if np.isinf(want):
            assert np.isinf(got[f]) or got[f] > 1e10
        else:
            np.testing.assert_allclose(got[f], want, rtol=1e-9)
