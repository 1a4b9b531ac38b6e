"""Tests of the evaluation metrics (mmsnap_graph.evaluation.metrics)."""

import numpy as np
import pytest
from numpy.testing import assert_allclose

from mmsnap_graph import ValidationError
from mmsnap_graph.evaluation import align_frames, chi2_mean_interval, nees, nees_check, pose_error, state_errors


def test_state_errors_known_values_and_skips_nonfinite_rows():
    ref = np.zeros((4, 4))
    est = np.array([[3.0, 4.0, 0.0, 1.0], [0.0, 0.0, 0.0, 1.0], [np.nan, 0, 0, 0], [0, 0, 0, 0]])
    est[3] = [0.0, 0.0, 0.0, 1.0]
    err = state_errors(est, ref)
    assert err.n_frames == 3
    assert_allclose(err.position_rmse_m, np.sqrt(25.0 / 3.0))
    assert_allclose(err.velocity_rmse_mps, 1.0)


def test_state_errors_shape_mismatch_raises():
    with pytest.raises(ValidationError, match="shape"):
        state_errors(np.zeros((3, 4)), np.zeros((2, 4)))


def test_align_frames_returns_common_indices_and_rejects_repeats():
    frames, ia, ib = align_frames([5, 1, 3, 9], [3, 4, 5])
    assert frames.tolist() == [3, 5]
    assert np.array_equal(np.array([5, 1, 3, 9])[ia], frames)
    assert np.array_equal(np.array([3, 4, 5])[ib], frames)
    with pytest.raises(ValidationError, match="repeated"):
        align_frames([1, 1], [1])


def test_pose_error_wraps_heading():
    err = pose_error([0.0, 7.0, -np.pi + 0.01], [0.3, 7.4, np.pi - 0.01])
    assert_allclose(err.position_error_m, 0.5)
    assert_allclose(err.heading_error_rad, 0.02, atol=1e-12)


def test_nees_is_chi_square_for_gaussian_errors():
    rng = np.random.default_rng(0)
    k, d = 4000, 4
    a = rng.normal(size=(k, d, d))
    cov = a @ np.swapaxes(a, 1, 2) + 0.1 * np.eye(d)
    e = np.einsum("kij,kj->ki", np.linalg.cholesky(cov), rng.normal(size=(k, d)))
    lo, hi = chi2_mean_interval(d, k)
    assert lo < nees(e, cov).mean() < hi
    # A covariance twice too large halves the NEES and falls outside.
    assert nees(e, 2 * cov).mean() < lo


def test_nees_check_passes_honest_covariances_and_flags_wrong_ones():
    """Seeded: 2,000 rows of 4-dof errors drawn from their covariances pass
    the 95% check; covariances four times too small (NEES x4) or too large
    (NEES /4) fail it."""
    rng = np.random.default_rng(3)
    k, d = 2000, 4
    a = rng.normal(size=(k, d, d))
    cov = a @ np.swapaxes(a, 1, 2) + 0.1 * np.eye(d)
    e = np.einsum("kij,kj->ki", np.linalg.cholesky(cov), rng.normal(size=(k, d)))
    ok = nees_check(e, cov)
    assert ok.passed and ok.n == k
    assert ok.interval == chi2_mean_interval(d, k, 0.95)
    assert nees_check(e, cov / 4).passed is False
    assert nees_check(e, cov * 4).passed is False


def test_nees_check_skips_failed_and_singular_rows():
    e = np.array([[1.0, 0.0], [np.nan, 0.0], [0.5, 0.5]])
    cov = np.stack([np.eye(2), np.eye(2), np.zeros((2, 2))])
    out = nees_check(e, cov)
    assert out.n == 1
    assert out.mean == pytest.approx(1.0)
    none = nees_check(e[1:], cov[1:])
    assert none.n == 0 and none.passed is None
    with pytest.raises(ValidationError, match="disagree"):
        nees_check(e, cov[:, :1])
