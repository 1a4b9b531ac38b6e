"""The stream's solver in plain floats (mmsnap_graph.fusion.solvers.scalar):
what tests/fusion/test_solve.py does not cover (its equality with GTSAM
through ``solve`` is there, the robust kernels included): a prior alone, a
network per frame refused."""

from __future__ import annotations

import numpy as np
import pytest

from _shared import PAPER_NOISE, PAPER_PRIOR, POSES_A
from mmsnap_graph.data.results import Status
from mmsnap_graph.errors import ValidationError
from mmsnap_graph.fusion.frame_problem import FrameProblem
from mmsnap_graph.fusion.options import FusionOptions
from mmsnap_graph.fusion.solve import solve

#: Four nodes around a 7 m square, each facing the centre (the stream benchmark's).
SQUARE = np.array([[0.0, 0.0, 0.0], [0.0, 7.0, np.pi], [-3.5, 3.5, -np.pi / 2], [3.5, 3.5, np.pi / 2]])
SCALAR = FusionOptions(solver="scalar")


def test_a_prior_alone_gives_the_prior():
    problem = FrameProblem(poses=SQUARE, measurements=np.zeros((4, 3)),
                           observed=np.zeros(4, dtype=bool), prior=PAPER_PRIOR)
    sol = solve(problem, SCALAR)
    assert sol.status.tolist() == [Status.OK]
    np.testing.assert_allclose(sol.state[0], PAPER_PRIOR.mean, atol=1e-12)
    np.testing.assert_allclose(sol.covariance[0], np.diag(PAPER_PRIOR.sigmas**2), rtol=1e-12)


def test_a_network_per_frame_is_refused():
    z = np.tile([[3.0, 0.1, 0.2], [3.5, -0.1, 0.1]], (2, 1, 1))
    problem = FrameProblem(poses=np.stack([POSES_A, POSES_A]), measurements=z,
                           noise=PAPER_NOISE)
    with pytest.raises(ValidationError, match="one network for every frame"):
        solve(problem, SCALAR)
    assert solve(problem, FusionOptions(solver="vectorized")).success.all()


def test_each_frame_starts_where_the_vectorized_initial_values_put_it():
    """The scalar solver's start of each frame (its solution's
    initial_state, computed from the frames as lists) is the numpy initial
    values of every frame at once (an independent computation) to 1e-12, and
    the given start when there is one; frames without a node or with a
    missing node included."""
    from mmsnap_graph.fusion.frame_problem import initial_states

    rng = np.random.default_rng(4)
    z = np.stack([rng.uniform(1.0, 6.0, (30, 4)), rng.uniform(-2.5, 2.5, (30, 4)),
                  rng.normal(0, 1, (30, 4))], axis=-1)
    obs = rng.random((30, 4)) < 0.7
    obs[0] = False
    problem = FrameProblem(poses=SQUARE, measurements=z, observed=obs, noise=PAPER_NOISE,
                           prior=PAPER_PRIOR)
    got = solve(problem, SCALAR).initial_state
    np.testing.assert_allclose(got, initial_states(problem), rtol=0, atol=1e-12)
    np.testing.assert_array_equal(got, initial_states(problem, per_frame=True))
    start = rng.uniform(0.5, 3.0, (30, 4))
    np.testing.assert_array_equal(solve(problem.with_initial_state(start), SCALAR).initial_state, start)


@pytest.mark.parametrize("prior", [PAPER_PRIOR, None], ids=["map", "ml"])
def test_residuals_cost_and_covariance_are_the_measurement_models(prior):
    """The solver's normal equations (from the float model) against
    factors.models.measurement_model in numpy at the solver's state:
    each observed node's whitened residuals (omega wrapped: frames near
    end-fire, |omega| close to pi), the final cost (with the prior's term)
    and the covariance, the inverse of J^T W J (+ the prior's information),
    to 1e-9 of sigma_i sigma_j; frames with a missed node included."""
    from factors.models import measurement_model, wrap_angle

    rng = np.random.default_rng(11)
    n_frames = 40
    truth = np.column_stack([rng.uniform(-2.5, 2.5, n_frames), rng.uniform(1.0, 6.0, n_frames),
                             rng.normal(0, 1, (n_frames, 2))])
    h, _ = measurement_model(truth[:, None, :], SQUARE[None])
    sigmas = np.array([PAPER_NOISE.range_m, PAPER_NOISE.omega_rad, PAPER_NOISE.doppler_mps])
    z = h + rng.normal(0, 1, h.shape) * sigmas
    z[:, :, 1] = np.clip(z[:, :, 1], -np.pi, np.pi)
    z[:8, 0, 1] = np.where(z[:8, 0, 1] < 0, -1.0, 1.0) * (np.pi - 1e-4 * rng.random(8))  # end-fire
    obs = np.ones((n_frames, 4), dtype=bool)
    obs[::5, 2] = False
    problem = FrameProblem(poses=SQUARE, measurements=z, observed=obs, noise=PAPER_NOISE,
                           prior=prior)
    sol = solve(problem, SCALAR)
    assert sol.success.all()
    pred, jac = measurement_model(sol.state[:, None, :], SQUARE[None])
    e = pred - z
    e[..., 1] = wrap_angle(e[..., 1])
    e = e / sigmas
    np.testing.assert_allclose(np.where(obs[..., None], sol.whitened_residuals, 0.0),
                               np.where(obs[..., None], e, 0.0), rtol=0, atol=1e-9)
    assert np.isnan(sol.whitened_residuals[~obs]).all()
    info = np.einsum("fnki,fnk,fnkj->fij", jac, obs[..., None] / sigmas**2, jac)
    cost = 0.5 * np.sum(np.where(obs[..., None], e, 0.0) ** 2, axis=(1, 2))
    if prior is not None:
        info = info + np.diag(1.0 / prior.sigmas**2)
        cost = cost + 0.5 * np.sum(((sol.state - prior.mean) / prior.sigmas) ** 2, axis=1)
    np.testing.assert_allclose(sol.final_cost, cost, rtol=1e-9)
    cov = np.linalg.inv(info)
    sig = np.sqrt(np.einsum("fii->fi", cov))
    gap = np.abs(sol.covariance - cov) / np.einsum("fi,fj->fij", sig, sig)
    assert gap.max() < 1e-9
