"""Vectorized one-shot fusion of many frames at once (docs/CONVENTIONS.md, "One-shot fusion").

The per-frame GTSAM solve (:mod:`mmsnap_graph.fusion.solvers.gtsam_graph`) costs a
factor graph, an optimizer and a ``Marginals`` object per frame. This module
solves the same problem, the same negative log posterior (paper eq. 18)

.. math::

    L(\\theta) = \\tfrac12 \\sum_i \\| (h(\\theta; S_i) \\ominus z_i) / \\sigma \\|^2
               + \\tfrac12 \\| (\\theta - m) / s \\|^2

(the prior term only for MAP), for ``F`` frames at once with a damped
Gauss-Newton (Levenberg-Marquardt) iteration written in numpy over the frame
axis. It calls the same measurement model as the GTSAM factors
(:func:`factors.models.measurement_model`), starts from the same initial values
(:func:`mmsnap_graph.fusion.frame_problem.initial_states`) and returns the
Laplace covariance, the inverse of the Gauss-Newton information matrix at the
solution (what ``gtsam.Marginals`` computes for this one-variable graph),
through a 4x4 Cholesky factorization vectorized over frames.

Frames where a node does not see the target are fused with the nodes that do
(``observed``); a frame whose information matrix is singular (ML with a single
node, say) is flagged, not raised.

How it is fast: the frames are solved in chunks of a few thousand, whose
temporaries stay in cache, for the few iterations most frames need; the frames
still running then continue together. Arrays are laid out frames-last, so that
every arithmetic operation runs over a contiguous array of frames, and the
4x4 factorizations are written entry by entry. Gauss-Newton converges only
linearly near a weakly observed minimum (a target near the line through two
radars, where the cross-line velocity rests on the prior); after
``newton_after`` steps a frame adds the second-order residual term, from
forward differences of the model's Jacobian, and converges quadratically to
the same minimum. :func:`solve_frames` is ``solver="vectorized"`` of
:func:`mmsnap_graph.fusion.solve.solve`.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from ..._linalg import chol_soa, from_soa, inverse_soa
from ...data.results import Status
from ...data.solution import FusionSolution
from ..degeneracy import velocity_degeneracy
from ..frame_problem import FrameProblem, initial_states
from ..options import DEFAULT_OPTIONS, FusionOptions
from ..robust import kernel_weight_and_loss, node_d2
from .vectorized_lm import SolverParams, evaluate, levenberg_marquardt
from .vectorized_poses import propagate_pose_covariance

__all__ = ["solve_frames"]

# Status codes (the status arrays are int8).
_CONVERGED, _MAX_ITER, _SINGULAR, _NONFINITE, _EMPTY = (
    int(Status.OK), int(Status.MAX_ITERATIONS), int(Status.SINGULAR), int(Status.NON_FINITE),
    int(Status.NO_INFORMATION))

# A chunk of the first stage stops when fewer than 1/16 of its frames are
# still running (the rest continue in the second stage, all chunks together).
_STAGE1_MIN_LIVE_FRACTION = 16

# Iterations of the chunked first stage (most frames converge within them).
_STAGE1_ITERATIONS = 8

_DIAG = np.arange(4)



#: A covariance whose information matrix has ``max diag / min Cholesky
#: pivot^2`` (a lower bound of its condition number) above this is flagged
#: singular: its smallest eigenvalues are lost to rounding.
_MAX_CONDITION = 1e13


def _solve(poses, z, obs, x0, params, max_iterations, chunk_size) -> FusionSolution:
    """Both stages of Levenberg-Marquardt, then the covariances and the result."""
    n_frames, n_nodes = z.shape[:2]
    weight = obs.astype(float)
    state = np.empty((n_frames, 4))
    cost = np.full(n_frames, np.nan)
    residuals = np.zeros((n_frames, n_nodes, 3))
    info = np.full((4, 4, n_frames), np.nan)
    iterations = np.zeros(n_frames, dtype=np.int64)
    status = np.full(n_frames, _EMPTY, dtype=np.int8)
    lam, nu = np.empty(n_frames), np.empty(n_frames)
    empty = ~obs.any(axis=1) if params.prior_mean is None else np.zeros(n_frames, dtype=bool)
    state[empty] = x0[empty]

    def run(rows, x_start, it_start, budget, min_live=0, damping=None):
        if rows.size == 0:
            return
        p_rows = poses[rows] if poses.ndim == 3 else poses
        out = levenberg_marquardt(x_start, p_rows, z[rows], weight[rows], params, it_start, budget,
                                  min_live, damping)
        state[rows], cost[rows], residuals[rows], info[:, :, rows], iterations[rows], status[rows] = out[:6]
        lam[rows], nu[rows] = out[6]

    # Model evaluations at a state on a node give NaN that the solver flags.
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        # Stage 1, in chunks that keep the temporaries in cache: the few steps
        # that most frames need. Stage 2: the frames still running, together.
        rows_all = np.flatnonzero(~empty)
        first = min(_STAGE1_ITERATIONS, max_iterations)
        for start in range(0, rows_all.size, chunk_size):
            rows = rows_all[start:start + chunk_size]
            run(rows, x0[rows], np.zeros(rows.size, dtype=np.int64), first,
                max(1, rows.size // _STAGE1_MIN_LIVE_FRACTION))
        left = rows_all[status[rows_all] == _MAX_ITER]
        if left.size and max_iterations > first:
            run(left, state[left].copy(), iterations[left].copy(), max_iterations,
                damping=(lam[left], nu[left]))

        # Laplace covariance: inverse of the undamped information at the solution.
        lo, pd = chol_soa(info)
        cov = from_soa(inverse_soa(lo))
        degeneracy = velocity_degeneracy(state, poses, obs)
        # success implies a positive-definite covariance to rounding: flag an
        # information matrix too ill-conditioned for its inverse's smallest
        # eigenvalues to survive (a finite but absurd Doppler, say).
        pivot2 = np.min([lo[j][j] for j in range(4)], axis=0) ** 2
        pd &= np.max(info[_DIAG, _DIAG], axis=0) <= _MAX_CONDITION * pivot2
    if params.kernel is not None:
        residuals = _whitened(state, poses, z, weight, params)
    residuals[~obs] = np.nan
    finite = np.all(np.isfinite(state), axis=1) & np.isfinite(cost)
    status[(status == _CONVERGED) & ~finite] = _NONFINITE
    status[(status == _CONVERGED) & ~pd] = _SINGULAR
    # As GTSAM's solve: no covariance for a frame that failed.
    cov[status != _CONVERGED] = np.nan
    return FusionSolution(state=state, covariance=cov, status=status, iterations=iterations,
                          final_cost=cost, initial_state=x0, whitened_residuals=residuals,
                          degeneracy=degeneracy)


def _whitened(state, poses, z, weight, params) -> NDArray:
    """Plain whitened residuals (F, N, 3) at ``state`` (zeros where unobserved)."""
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        aug, _ = evaluate(state, poses, z, weight, params.inv_sigma, None, None)
    return aug[:, 4].T.reshape(state.shape[0], -1, 3).copy()


def _with_pose_covariance(solution: FusionSolution, poses, obs, params, pose_cov
                          ) -> FusionSolution:
    """The calibration-aware covariance of the solved frames (linear
    propagation), each node weighted as in the kernel fit."""
    weights = None
    if params.kernel is not None:
        s2 = np.nan_to_num(node_d2(solution.whitened_residuals))
        weights = kernel_weight_and_loss(params.kernel[0], params.kernel[1], s2)[0]
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        cov = propagate_pose_covariance(solution.covariance, solution.state, poses, obs,
                                        params.inv_sigma, pose_cov, weights)
    cov[~solution.success] = np.nan
    return replace(solution, covariance=cov)


def solve_frames(problem: FrameProblem, options: FusionOptions = DEFAULT_OPTIONS
                 ) -> FusionSolution:
    """Every frame of a :class:`~mmsnap_graph.fusion.frame_problem.FrameProblem`
    solved together (Levenberg-Marquardt vectorized over the frames): a
    :class:`~mmsnap_graph.data.solution.FusionSolution` with the Laplace
    covariance (:func:`mmsnap_graph.fusion.solve.solve`). ``options.lm.max_steps``
    steps per frame, rejected ones included (GTSAM's ``lm.max_iterations``
    counts outer iterations, each of which may try several damping values);
    a frame converges when an accepted step is below ``options.step_tolerance
    * (1 + |x|)`` in every component or no step lowers the cost any more;
    after ``options.newton_after`` steps a frame adds the second-order
    residual term (Newton's quadratic convergence near a weakly observed
    minimum; the minimum and the Laplace covariance are unchanged);
    ``options.chunk_size`` frames are solved together in the first steps.
    With uncertain poses the covariance adds theirs by linear propagation,
    ``P = P_x + A Sigma_p A^T`` (:mod:`~.vectorized_poses`)."""
    prior = problem.prior
    params = SolverParams(
        inv_sigma=1.0 / problem.sigmas,
        prior_mean=None if prior is None else np.asarray(prior.mean, dtype=float),
        prior_inv_sigma=None if prior is None else 1.0 / np.asarray(prior.sigmas, dtype=float),
        step_tolerance=options.step_tolerance, newton_after=options.newton_after,
        kernel=problem.kernel, lm=options.lm)
    x0 = initial_states(problem)
    solution = _solve(problem.poses, problem.measurements, problem.observed, x0, params,
                      options.lm.max_steps, options.chunk_size)
    if problem.pose_covariances is not None:
        solution = _with_pose_covariance(solution, problem.poses, problem.observed, params,
                                         problem.pose_covariances)
    return solution
