"""Result records of the estimators (mmsnap_graph.data.results)."""

from __future__ import annotations

import numpy as np

from mmsnap_graph.data.noise import GaussianPrior
from mmsnap_graph.data.results import measurement_information


def test_measurement_information_removes_the_prior_exactly():
    prior = GaussianPrior(mean=[1.0, 2.0, 0.5, -0.5], sigmas=[2.0, 3.0, 1.5, 2.5])
    rng = np.random.default_rng(0)
    a = rng.normal(size=(3, 4, 4))
    y_true = a @ np.swapaxes(a, -1, -2) + 0.5 * np.eye(4)
    x = rng.normal(size=(3, 4))
    cov = np.linalg.inv(y_true + prior.information)
    info, vec = measurement_information(x, cov, prior.mean, prior.sigmas)
    np.testing.assert_allclose(info, y_true, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(vec, np.einsum("kij,kj->ki", np.linalg.inv(cov), x)
                               - prior.information @ prior.mean, rtol=1e-9, atol=1e-9)
    # A NaN or indefinite covariance gives NaN rows, not an error.
    bad = cov.copy()
    bad[0] = np.nan
    bad[1] = -np.eye(4)
    info, vec = measurement_information(x, bad)
    assert np.all(np.isnan(info[:2])) and np.all(np.isnan(vec[:2]))
    assert np.all(np.isfinite(info[2]))
