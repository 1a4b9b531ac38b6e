"""Batched small-matrix algebra (mmsnap_graph._linalg) against numpy's
per-matrix Cholesky, solve and inverse."""

from __future__ import annotations

import numpy as np
import pytest

from mmsnap_graph._linalg import (cholesky4, cholesky4_inverse, cholesky4_solve, from_soa,
                                  symmetrize, to_soa)


def _spd_stack(rng, n_frames, n=4):
    a = rng.normal(size=(n_frames, n, n))
    return a @ np.swapaxes(a, 1, 2) + 0.1 * np.eye(n)


@pytest.mark.parametrize("n", [2, 3, 4])
def test_stacked_cholesky_solve_and_inverse_match_numpy(n):
    rng = np.random.default_rng(n)
    a = _spd_stack(rng, 50, n)
    chol, ok = cholesky4(a)
    assert ok.all() and chol.shape == a.shape
    np.testing.assert_allclose(chol, np.linalg.cholesky(a), rtol=1e-9, atol=1e-12)
    b = rng.normal(size=(50, n))
    np.testing.assert_allclose(cholesky4_solve(chol, b), np.linalg.solve(a, b[..., None])[..., 0],
                               rtol=1e-8, atol=1e-10)
    inv = cholesky4_inverse(chol)
    np.testing.assert_allclose(inv, np.linalg.inv(a), rtol=1e-8, atol=1e-10)
    np.testing.assert_array_equal(inv, np.swapaxes(inv, 1, 2))


def test_singular_indefinite_and_non_finite_matrices_are_flagged_not_raised():
    rng = np.random.default_rng(0)
    a = _spd_stack(rng, 6)
    a[1] = np.diag([1.0, 1.0, 1.0, 0.0])
    a[2] = np.diag([1.0, -2.0, 1.0, 1.0])
    v = rng.normal(size=4)
    a[3] = np.outer(v, v)  # rank one
    a[4, 0, 0] = np.nan
    chol, ok = cholesky4(a)
    assert ok.tolist() == [True, False, False, False, False, True]
    assert np.all(np.isfinite(chol[~np.isnan(a).any(axis=(1, 2))]))
    np.testing.assert_allclose(chol[ok], np.linalg.cholesky(a[ok]), rtol=1e-9)


def test_layout_round_trip_and_symmetrize():
    a = np.arange(2 * 3 * 4 * 4, dtype=float).reshape(2, 3, 4, 4)
    t = to_soa(a)
    assert t.shape == (4, 4, 2, 3) and t.flags.c_contiguous
    np.testing.assert_array_equal(from_soa(t), a)
    s = symmetrize(a)
    np.testing.assert_array_equal(s, np.swapaxes(s, -1, -2))
    np.testing.assert_array_equal(s, 0.5 * (a + np.swapaxes(a, -1, -2)))
