"""The paper's grid posterior (mmsnap_graph.fusion.grid): its layout checks,
exactness on a Gaussian posterior, widening and the truncation report."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose

from _shared import POSES_B
from factors.models import measurement_model
from mmsnap_graph.data.noise import GaussianPrior
from mmsnap_graph.errors import ValidationError
from mmsnap_graph.fusion.grid import grid_posterior

TRUTH_B = np.array([0.5, 4.5, 0.6, -0.4])


def exact(poses, truth):
    return measurement_model(truth, poses)[0]


def test_grid_posterior_validates_its_layout():
    z = exact(POSES_B, TRUTH_B)
    with pytest.raises(ValidationError, match="points_per_axis must be odd and >= 5, got 4"):
        grid_posterior(TRUTH_B, POSES_B, z, scale_covariance=np.eye(4), points_per_axis=4)
    with pytest.raises(ValidationError, match="scale_covariance must be positive definite"):
        grid_posterior(TRUTH_B, POSES_B, z, scale_covariance=-np.eye(4))
    with pytest.raises(ValidationError, match="half_width_sigmas must be finite and > 0"):
        grid_posterior(TRUTH_B, POSES_B, z, scale_covariance=np.eye(4), half_width_sigmas=0)


def test_grid_posterior_of_a_linear_gaussian_is_exact():
    """A grid laid along the exact covariance of a Gaussian posterior
    returns it: a prior-only posterior (no node observed)."""
    prior = GaussianPrior(mean=[1.0, 2.0, 0.3, -0.1], sigmas=[0.5, 1.5, 2.0, 0.7])
    grid = grid_posterior(
        prior.mean, POSES_B, np.full((2, 3), np.nan), observed=np.zeros(2, bool),
        prior=prior, scale_covariance=np.diag(prior.sigmas**2) * 1.3, points_per_axis=15,
    )
    assert_allclose(grid.mean, prior.mean, atol=1e-9)
    assert_allclose(grid.covariance, np.diag(prior.sigmas**2), rtol=1e-4, atol=1e-12)
    assert grid.edge_density < 1e-4 and grid.message == ""


def test_grid_posterior_widens_and_reports_truncation():
    """A grid laid out far too narrow is widened (doubling its half-width),
    and when it still cuts the posterior off, the result says so."""
    prior = GaussianPrior(mean=[0.0, 0.0, 0.0, 0.0], sigmas=[1.0, 1.0, 1.0, 1.0])
    kw = dict(observed=np.zeros(2, bool), prior=prior, points_per_axis=9)
    z = np.full((2, 3), np.nan)
    # Laplace-like scale 4x too small: +-5 "sigmas" is +-1.25 true sigmas;
    # two doublings reach +-5 true sigmas.
    widened = grid_posterior(prior.mean, POSES_B, z, scale_covariance=np.eye(4) / 16, **kw)
    assert widened.half_width_sigmas == 20.0 and widened.message == ""
    assert_allclose(widened.covariance, np.eye(4), rtol=0.02, atol=1e-3)
    # No widening allowed: truncated, and flagged.
    cut = grid_posterior(prior.mean, POSES_B, z, scale_covariance=np.eye(4) / 16, max_widenings=0, **kw)
    assert "grid posterior truncated" in cut.message
    assert cut.edge_density > 0.1
    assert cut.half_width_sigmas == 5.0
    assert np.all(np.diag(cut.covariance) < 0.6)  # the truncated grid underestimates
