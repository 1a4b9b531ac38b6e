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
