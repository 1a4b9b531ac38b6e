"""The vectorized Levenberg-Marquardt iterations
(mmsnap_graph.fusion.solvers.vectorized_lm): the Newton term against a
finite-difference Hessian, and a frame's steps independent of the frames it
is solved with."""

from __future__ import annotations

import numpy as np

from _shared import PAPER_NOISE, PAPER_PRIOR, POSES_B, POSES_C
from factors.models import predict_measurements, wrap_angle
from _fusion import solved
from mmsnap_graph.fusion import FrameProblem, FusionOptions, initial_states
from mmsnap_graph.fusion.solvers.vectorized_lm import evaluate, normal_equations, residual_curvature


def _frames(seed, n, poses, centre, spread=1.0):
    rng = np.random.default_rng(seed)
    states = np.column_stack([centre[0] + spread * rng.uniform(-1, 1, n),
                              centre[1] + spread * rng.uniform(-1, 1, n),
                              rng.normal(0.0, 0.8, (n, 2))])
    z = np.stack([predict_measurements(s, poses) for s in states])
    z += rng.normal(size=z.shape) * PAPER_NOISE.sigmas
    z[..., 1] = wrap_angle(z[..., 1])
    return z


def test_residual_curvature_matches_finite_difference_hessian():
    """GN information + curvature term = the Hessian of the cost."""
    z = _frames(7, 5, POSES_B, (0.5, 4.0))
    x = initial_states(FrameProblem(poses=POSES_B, measurements=z, prior=None))
    w = np.ones((5, 2))
    inv = 1.0 / PAPER_NOISE.sigmas
    aug, _ = evaluate(x, POSES_B, z, w, inv, None, None)
    info, _ = normal_equations(x, aug, None, None)
    full = info + residual_curvature(x, POSES_B, z, w, inv, aug)

    def cost(s):
        return evaluate(s, POSES_B, z, w, inv, None, None)[1]

    eps = 1e-4
    hess = np.zeros((4, 4, 5))
    for i in range(4):
        for j in range(4):
            e_i, e_j = np.eye(4)[i] * eps, np.eye(4)[j] * eps
            hess[i, j] = (cost(x + e_i + e_j) - cost(x + e_i - e_j) - cost(x - e_i + e_j)
                          + cost(x - e_i - e_j)) / (4 * eps**2)
    np.testing.assert_allclose(full, hess, rtol=2e-4, atol=2e-3)


def test_a_frames_answer_does_not_depend_on_its_chunk():
    """Near configuration C's degenerate line most frames need more than the
    first stage's iterations; a frame that continues in the second stage goes
    on from its own damping, so the same frame gives the same answer however
    the frames are chunked: statuses equal, states to rounding (measured on
    three seeds: 1.2e-8 of a sigma at most; bound 1e-7)."""
    for seed, spread in ((11, 0.4), (3, 1.0)):
        z = _frames(seed, 256, POSES_C, (0.0, 3.5), spread)
        ref = solved(POSES_C, z, solver="vectorized", prior=PAPER_PRIOR)
        assert ref.iterations.max() > 8  # frames reach the second stage
        sig = np.sqrt(np.einsum("fii->fi", ref.covariance))
        for chunk in (1, 5, 16):
            got = solved(POSES_C, z, solver="vectorized", prior=PAPER_PRIOR,
                         options=FusionOptions(chunk_size=chunk))
            np.testing.assert_array_equal(got.status, ref.status)
            ok = ref.success
            assert np.max(np.abs(got.state - ref.state)[ok] / sig[ok]) <= 1e-7
