"""Tests of the evaluation metrics (mmsnap_graph.app.evaluation)."""

import numpy as np
import pytest
from numpy.testing import assert_allclose

from mmsnap_graph import ValidationError
from mmsnap_graph.app.evaluation import align_frames, chi2_mean_interval, nees, pose_error, state_errors


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
