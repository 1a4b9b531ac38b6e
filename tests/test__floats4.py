"""Symmetric 4x4 algebra in plain floats (mmsnap_graph._floats4) against
numpy's Cholesky, solve and inverse."""

from __future__ import annotations

import numpy as np
import pytest

from mmsnap_graph._floats4 import (cholesky_4x4, cholesky_inverse_4x4, cholesky_solve_4x4,
                                   forward_4x4)


def _spd(rng, cond=1e3):
    """A random 4x4 SPD matrix of condition number ``cond``."""
    q, _ = np.linalg.qr(rng.normal(size=(4, 4)))
    return q @ np.diag(np.geomspace(1.0, 1.0 / cond, 4)) @ q.T * rng.uniform(0.1, 10)


def _lower(lo):
    l00, l10, l11, l20, l21, l22, l30, l31, l32, l33 = lo
    return np.array([[l00, 0, 0, 0], [l10, l11, 0, 0], [l20, l21, l22, 0], [l30, l31, l32, l33]])


@pytest.mark.parametrize("seed", range(5))
def test_factor_solve_and_inverse_match_numpy(seed):
    rng = np.random.default_rng(seed)
    a = _spd(rng)
    lo = cholesky_4x4(a.ravel().tolist())
    assert lo is not None
    np.testing.assert_allclose(_lower(lo), np.linalg.cholesky(a), rtol=1e-10, atol=1e-12)
    b = rng.normal(size=4)
    np.testing.assert_allclose(forward_4x4(lo, b), np.linalg.solve(np.linalg.cholesky(a), b),
                               rtol=1e-9)
    np.testing.assert_allclose(cholesky_solve_4x4(lo, b), np.linalg.solve(a, b), rtol=1e-9)
    inv = np.array(cholesky_inverse_4x4(lo)).reshape(4, 4)
    np.testing.assert_allclose(inv, np.linalg.inv(a), rtol=1e-9, atol=1e-12)
    np.testing.assert_array_equal(inv, inv.T)  # exactly symmetric


@pytest.mark.parametrize("a", [
    np.diag([1.0, 1.0, 1.0, 0.0]),                      # singular
    np.diag([1.0, -1.0, 1.0, 1.0]),                     # indefinite
    np.ones((4, 4)),                                    # rank one
    np.diag([1.0, 1.0, np.nan, 1.0]),                   # not finite
    np.diag([1.0, 1.0, 1.0, np.inf]),
], ids=["singular", "indefinite", "rank-one", "nan", "inf"])
def test_matrices_that_are_not_positive_definite_give_none(a):
    assert cholesky_4x4(a.ravel().tolist()) is None
