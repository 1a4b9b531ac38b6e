"""Constant-velocity motion model (factors.motion) against independent
references: the transition as the matrix exponential of the continuous
kinematics, the discrete process noise as the covariance of a simulated
constant acceleration per step, the continuous one as the integral of
F(s) G G^T F(s)^T by numerical quadrature; and the GTSAM motion factor
carries that continuous covariance."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy import integrate, linalg

from factors import cv_process_noise, cv_process_noise_continuous, cv_transition

# Continuous kinematics of (x, y, vx, vy): d/dt state = A state + G a.
A = np.zeros((4, 4))
A[0, 2] = A[1, 3] = 1.0
G = np.array([[0.0, 0.0], [0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])


@pytest.mark.parametrize("t", [0.05, 0.15, 1.3])
def test_transition_is_the_exponential_of_the_kinematics(t):
    assert_allclose(cv_transition(t), linalg.expm(A * t), rtol=1e-14, atol=1e-15)


@pytest.mark.parametrize("t, sigma_a", [(0.15, 0.2), (0.4, 1.0)])
def test_continuous_noise_is_the_integral_of_the_white_acceleration(t, sigma_a):
    q = sigma_a**2 * t  # the spectral density that matches the discrete velocity variance

    def integrand(s):
        f = linalg.expm(A * s)
        return (f @ G) @ (f @ G).T * q

    ref, _ = integrate.quad_vec(integrand, 0.0, t, epsabs=1e-16, epsrel=1e-12)
    got = cv_process_noise_continuous(t, sigma_a)
    assert_allclose(got, ref, rtol=1e-10, atol=1e-18)
    assert np.all(np.linalg.eigvalsh(got) > 0)  # full rank: it can whiten a factor
    # Same velocity-increment variance as the discrete form.
    assert_allclose(np.diag(got)[2:], np.diag(cv_process_noise(t, sigma_a))[2:], rtol=1e-14)


def test_discrete_noise_is_the_covariance_of_a_constant_acceleration_per_step():
    """Integrate x' = v, v' = a with a drawn once per step (fine Euler-Heun
    substeps, exact for constant a) and compare the state increments'
    covariance with Q."""
    rng = np.random.default_rng(0)
    t, sigma_a, n, sub = 0.3, 0.8, 100_000, 16
    a = sigma_a * rng.standard_normal((n, 2))
    pos = np.zeros((n, 2))
    vel = np.zeros((n, 2))
    h = t / sub
    for _ in range(sub):
        pos += h * vel + 0.5 * h * h * a
        vel += h * a
    emp = np.cov(np.hstack([pos, vel]).T)
    q = cv_process_noise(t, sigma_a)
    scale = np.sqrt(np.outer(np.diag(q), np.diag(q)))
    assert_allclose(emp / scale, q / scale, atol=0.02)
    # Rank one per axis (a single acceleration per step drives both).
    assert np.linalg.matrix_rank(q[np.ix_([0, 2], [0, 2])]) == 1


def test_zero_acceleration_noise_is_zero():
    assert np.all(cv_process_noise(0.15, 0.0) == 0.0)
    assert np.all(cv_process_noise_continuous(0.15, 0.0) == 0.0)


def test_gtsam_motion_factor_uses_the_continuous_form():
    pytest.importorskip("gtsam")
    from factors.gtsam_factors import constant_velocity_factor

    t, sigma_a = 0.45, 0.7
    r = constant_velocity_factor(1, 2, t, sigma_a).noiseModel().R()
    assert_allclose(np.linalg.inv(r.T @ r), cv_process_noise_continuous(t, sigma_a),
                    rtol=1e-9, atol=1e-15)
