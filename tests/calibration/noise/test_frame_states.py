"""Each frame's least-squares target state at known poses
(mmsnap_graph.calibration.noise.frame_states) against a different solver:
the vectorized one-shot fusion (``solve``, ``solver="vectorized"``) with the same weights and
prior."""

from __future__ import annotations

import numpy as np

from factors.models import predict_measurements
from _fusion import solved
from mmsnap_graph import MeasurementNoise
from mmsnap_graph.calibration.noise.frame_states import solve_frame_states
from mmsnap_graph.fusion import FusionOptions

from _shared import POSES_BC

NOISE = MeasurementNoise(range_m=0.05, omega_rad=0.08, doppler_mps=0.10)
PRIOR_SIGMAS = np.array([30.0, 30.0, 10.0, 10.0])


def _frames(seed, n_frames=30):
    rng = np.random.default_rng(seed)
    states = np.column_stack([rng.uniform(0.5, 3.5, n_frames), rng.uniform(2.0, 5.0, n_frames),
                              rng.normal(0.0, 0.8, (n_frames, 2))])
    z = np.stack([predict_measurements(states, p) for p in POSES_BC], axis=1)
    return states, z + rng.normal(size=z.shape) * NOISE.sigmas


def test_states_are_the_prior_free_estimate_of_the_vectorized_solve():
    """The Gauss-Newton steps use the prior's information but not its
    gradient, so the prior damps the steps and the fixed point is the
    prior-free (ML) estimate: the vectorized solve's state (``prior=None``) (1e-7 m);
    the covariance returned is ``(J^T W J + prior_w)^-1`` at that state
    (1e-6 of sigma_i sigma_j)."""
    _, z = _frames(0)
    w = np.broadcast_to(1.0 / NOISE.sigmas**2, z.shape)
    prior_w = 1.0 / PRIOR_SIGMAS**2
    x, e, jac, cov = solve_frame_states(z, POSES_BC, w, prior_w, iterations=12)
    ref = solved(POSES_BC, z, solver="vectorized", noise=NOISE, prior=None,
                 options=FusionOptions(step_tolerance=1e-14))
    assert ref.success.all()
    np.testing.assert_allclose(x, ref.state, atol=1e-7)
    expected = np.linalg.inv(np.linalg.inv(ref.covariance) + np.diag(prior_w))
    sig = np.sqrt(np.einsum("fii->fi", expected))
    scale = sig[:, :, None] * sig[:, None, :]
    np.testing.assert_allclose(cov / scale, expected / scale, atol=1e-6)
    # the residuals and Jacobians are those at the solution: J^T W e vanishes
    grad = np.einsum("fnri,fnr,fnr->fi", jac, w, e)
    assert np.max(np.abs(grad * sig)) < 1e-6


def test_an_unseen_node_is_left_out_and_its_residuals_are_nan():
    """Frames that S3 does not see (NaN) give the state of the S1-S2 solve."""
    _, z = _frames(1, 12)
    w = np.broadcast_to(1.0 / NOISE.sigmas**2, z.shape).copy()
    z_miss = z.copy()
    z_miss[::2, 2] = np.nan
    w[::2, 2] = 0.0
    x, e, _, _ = solve_frame_states(z_miss, POSES_BC, w, 1.0 / PRIOR_SIGMAS**2, iterations=12)
    assert np.all(np.isnan(e[::2, 2])) and np.all(np.isfinite(e[1::2]))
    two, _, _, _ = solve_frame_states(z[::2, :2], POSES_BC[:2], w[::2, :2],
                                      1.0 / PRIOR_SIGMAS**2, iterations=12)
    np.testing.assert_allclose(x[::2], two, atol=1e-9)


def test_a_numerically_singular_frame_is_left_unsolved_not_raised():
    """Before: one frame whose range weight dwarfs the others' (a range sigma
    of 1e-16 m from ranges rounded to whole metres) raised LinAlgError out of
    `mmsnap calibrate` and `mmsnap noise`. Now that frame is NaN and the
    others are solved as before."""
    from mmsnap_graph.calibration.noise.frame_states import without_unsolved

    _, z = _frames(1, n_frames=6)
    w = np.array(np.broadcast_to(1.0 / NOISE.sigmas**2, z.shape))
    prior_w = 1.0 / PRIOR_SIGMAS**2
    ref = solve_frame_states(z, POSES_BC, w, prior_w)
    w[2, :, 0] = 1e32
    x, e, jac, cov = solve_frame_states(z, POSES_BC, w, prior_w)
    assert np.all(np.isnan(x[2])) and np.all(np.isnan(e[2])) and np.all(np.isnan(cov[2]))
    others = np.arange(6) != 2
    np.testing.assert_allclose(x[others], ref[0][others], rtol=0, atol=1e-12)
    np.testing.assert_allclose(cov[others], ref[3][others], rtol=1e-12, atol=0)
    w2, jac2, cov2 = without_unsolved(w, jac, cov)
    assert np.all(w2[2] == 0) and np.all(jac2[2] == 0) and np.all(cov2[2] == 0)
    assert np.array_equal(w2[others], w[others]) and np.array_equal(cov2[others], cov[others])


def test_the_determinant_screen_decides_as_the_eigenvalues_do():
    """solve_information(psd=True) skips the eigenvalues of frames whose determinant
    proves them well conditioned; its frames solved and its solutions equal
    the eigenvalue test's on well-conditioned, singular, barely regular and
    not-finite information."""
    from mmsnap_graph.calibration.noise.frame_states import SINGULAR_RCOND, solve_information

    rng = np.random.default_rng(3)
    a = rng.normal(size=(400, 6, 4))
    info = np.einsum("fki,fkj->fij", a, a)
    u = np.linalg.qr(rng.normal(size=(60, 4, 4)))[0]
    ratio = np.geomspace(1e-16, 1e-10, 60)  # around SINGULAR_RCOND = 1e-13, both sides
    info[:60] = np.einsum("fij,fj,fkj->fik", u, np.c_[ratio, np.ones((60, 3))], u)
    info[60] = 0.0
    info[61, 0, 0] = np.nan
    info[62] *= 1e200  # trace^4 overflows: decided by the eigenvalues
    info[63] *= 1e-90  # det underflows: decided by the eigenvalues
    info[64, 1, 2] = info[64, 2, 1] = np.inf  # not finite off the diagonal
    info[65, 3, 3] = -np.inf
    info[66] = np.diag([1.0, 1.0, 0.0, 1.0])
    info[66, 2, 2] = np.inf  # inf times a zero minor: NaN, not finite either
    info[67, 0, 1] = np.nan
    rhs = rng.normal(size=(400, 4, 1))
    out_e, ok_e = solve_information(info, rhs)
    out_d, ok_d = solve_information(info, rhs, psd=True)
    np.testing.assert_array_equal(ok_d, ok_e)
    np.testing.assert_array_equal(out_d, out_e)
    assert 10 < np.count_nonzero(~ok_e[:60]) < 50 and not ok_e[60] and not ok_e[61]
    assert ok_e[62] and ok_e[63] and not ok_e[64:68].any() and ok_e[68:].all()
    assert SINGULAR_RCOND == 1e-13


def test_the_closed_form_determinant_is_lapacks_to_rounding():
    """det_4x4 (the screen's determinant, 2x2 minors) against np.linalg.det."""
    from mmsnap_graph.calibration.noise.frame_states import det_4x4

    rng = np.random.default_rng(4)
    a = rng.normal(size=(500, 4, 4)) * rng.uniform(0.1, 10.0, size=(500, 1, 1))
    ref = np.linalg.det(a)
    np.testing.assert_allclose(det_4x4(a), ref, rtol=1e-9, atol=1e-12 * np.abs(ref).max())
    assert det_4x4(np.zeros((0, 4, 4))).shape == (0,)
