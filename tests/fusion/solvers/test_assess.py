"""Assessing a solved frame (mmsnap_graph.fusion.solvers.assess), shared by
the GTSAM and scalar solvers: residuals, gradient and degeneracy in one pass,
the covariance check, the Newton-decrement check."""

from __future__ import annotations

import numpy as np
import pytest

from _shared import PAPER_NOISE, PAPER_PRIOR, POSES_B, POSES_C
from factors.models import predict_measurements
from mmsnap_graph.data.results import Status
from mmsnap_graph.fusion.degeneracy import velocity_degeneracy
from mmsnap_graph.fusion.robust import kernel_weight_and_loss
from mmsnap_graph.fusion.solvers.assess import (
    NEWTON_DECREMENT_TOLERANCE,
    assess_fit,
    kernel_weight,
    positive_definite,
    residuals_and_degeneracy,
)

TRUTH_B = np.array([0.5, 4.5, 0.6, -0.4])
NOISES = [PAPER_NOISE] * 2


def test_residuals_gradient_and_degeneracy_at_the_truth():
    z = predict_measurements(TRUTH_B, POSES_B)
    whitened, degeneracy, grad = residuals_and_degeneracy(TRUTH_B, POSES_B, z, None, NOISES, None)
    np.testing.assert_allclose(whitened, 0.0, atol=1e-12)
    np.testing.assert_allclose(grad, 0.0, atol=1e-9)
    assert degeneracy == pytest.approx(velocity_degeneracy(TRUTH_B, POSES_B, None), rel=1e-12)
    # a node left out has NaN residuals; the prior adds its own gradient
    whitened, _, grad = residuals_and_degeneracy(TRUTH_B, POSES_B, z, np.array([True, False]),
                                                 NOISES, PAPER_PRIOR)
    assert np.isnan(whitened[1]).all()
    np.testing.assert_allclose(grad, (TRUTH_B - PAPER_PRIOR.mean) / PAPER_PRIOR.sigmas**2,
                               atol=1e-9)


def test_the_gradient_is_the_costs():
    rng = np.random.default_rng(2)
    z = predict_measurements(TRUTH_B, POSES_B) + rng.normal(size=(2, 3)) * PAPER_NOISE.sigmas
    x = TRUTH_B + 0.05

    def cost(s):
        w, _, _ = residuals_and_degeneracy(s, POSES_B, z, None, NOISES, PAPER_PRIOR)
        d = (s - PAPER_PRIOR.mean) / PAPER_PRIOR.sigmas
        return 0.5 * (np.sum(w**2) + d @ d)

    _, _, grad = residuals_and_degeneracy(x, POSES_B, z, None, NOISES, PAPER_PRIOR)
    eps = 1e-6
    numeric = [(cost(x + eps * e) - cost(x - eps * e)) / (2 * eps) for e in np.eye(4)]
    np.testing.assert_allclose(grad, numeric, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("name, k", [("huber", 1.345), ("cauchy", 2.5)])
def test_kernel_weight_is_the_kernels(name, k):
    s2 = np.array([0.1, 1.0, 4.0, 30.0])
    want = kernel_weight_and_loss(name, k, s2)[0]
    np.testing.assert_allclose([kernel_weight((name, k), v) for v in s2], want, rtol=1e-12)


def test_positive_definite():
    assert positive_definite(np.eye(4))
    assert not positive_definite(np.diag([1.0, 1.0, 1.0, 0.0]))
    assert not positive_definite(np.diag([1.0, 1.0, 1.0, 1e-15]))  # below the eigenvalue ratio
    assert not positive_definite(np.full((4, 4), np.nan))


def test_assess_fit_flags_a_point_away_from_the_minimum():
    z = predict_measurements(TRUTH_B, POSES_B)
    cov = np.diag([0.01, 0.01, 0.04, 0.04])
    status, messages, _, _ = assess_fit(TRUTH_B, cov, POSES_B, z, None, NOISES, None)
    assert status == Status.OK and messages == ["converged"]
    status, messages, _, _ = assess_fit(TRUTH_B + 0.3, cov, POSES_B, z, None, NOISES, None)
    assert status == Status.NON_FINITE and "Newton decrement" in messages[0]
    assert f"{NEWTON_DECREMENT_TOLERANCE:g}" in messages[0]
    status, _, _, _ = assess_fit(TRUTH_B, -cov, POSES_B, z, None, NOISES, None)
    assert status == Status.SINGULAR
    on_line = np.array([0.0, 3.5, 0.8, 0.5])  # configuration C's degenerate line
    status, messages, _, degeneracy = assess_fit(on_line, cov, POSES_C,
                                                 predict_measurements(on_line, POSES_C), None,
                                                 NOISES, PAPER_PRIOR)
    assert degeneracy > 100 and "degenerate geometry" in messages[-1]
