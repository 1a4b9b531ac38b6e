"""Vectorized one-shot fusion of many frames at once (docs/CONVENTIONS.md, "One-shot fusion").

The per-frame GTSAM solve (:func:`mmsnap_graph.fusion.solvers.gtsam_graph.fuse_frame`) costs a
factor graph, an optimizer and a ``Marginals`` object per frame. This module
solves the same problem, the same negative log posterior (paper eq. 18)

.. math::

    L(\\theta) = \\tfrac12 \\sum_i \\| (h(\\theta; S_i) \\ominus z_i) / \\sigma \\|^2
               + \\tfrac12 \\| (\\theta - m) / s \\|^2

(the prior term only for MAP), for ``F`` frames at once with a damped
Gauss-Newton (Levenberg-Marquardt) iteration written in numpy over the frame
axis. It calls the same measurement model as the GTSAM factors
(:func:`factors.models.measurement_model`), starts from the same initial values
(:func:`mmsnap_graph.fusion.problem.initial_states`) and returns the
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
the same minimum.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Literal, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ...errors import ValidationError
from ..._linalg import chol_soa, cholesky4, cholesky4_inverse, cholesky4_solve, from_soa, inverse_soa
from ..._validation import as_float_array, check_finite
from ...data.noise import GaussianPrior, MeasurementNoise
from ...data.results import BatchResult, Status
from ...data.solution import FusionSolution
from .vectorized_poses import propagate_pose_covariance
from ..problem import (
    check_node_noise,
    check_pose_covariances,
    check_prior,
    initial_states,
    node_sigmas,
    validate_frames,
    velocity_degeneracy,
)
from .vectorized_lm import SolverParams, evaluate, levenberg_marquardt
from ..options import DEFAULT_OPTIONS, FusionOptions, RobustOptions, check_options, robust_options
from ..frame_problem import initial_states
from ..robust import kernel_weight_and_loss, node_d2, residual_test_fails

__all__ = [
    "BatchResult",
    "fuse_batch",
    "cholesky4",
    "cholesky4_solve",
    "cholesky4_inverse",
]

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



def fuse_batch(
    node_poses: ArrayLike,
    measurements: ArrayLike,
    *,
    observed: ArrayLike | None = None,
    noise: MeasurementNoise | Sequence[MeasurementNoise] = MeasurementNoise(),
    prior: GaussianPrior | None = GaussianPrior(),
    initial_state: ArrayLike | None = None,
    pose_covariances: ArrayLike | None = None,
    robust: RobustOptions | Literal["gate", "huber", "cauchy"] | None = None,
    options: FusionOptions = DEFAULT_OPTIONS,
) -> BatchResult:
    """Fuse ``F`` frames of ``N`` nodes' measurements at once (MAP or ML).

    Parameters
    ----------
    node_poses : (N, 3) or (F, N, 3) float
        Node poses ``(x_m, y_m, phi_rad)`` in the global frame.
    measurements : (F, N, 3) float
        ``(range_m, omega_rad, doppler_mps)`` of each node at each frame. The
        missing-data convention of :func:`~.problem.validate_frames`: without
        ``observed`` an all-NaN row means "not observed"; observed rows need
        ``0 < range < inf``, ``|omega| <= pi`` and a finite Doppler.
    observed : (F, N) bool, optional
        Which nodes see the target at each frame (default: the rows that are
        not all NaN); unobserved rows may hold anything.
    noise : MeasurementNoise or sequence of N MeasurementNoise
        Measurement sigmas (default: the paper's), or one per node in the
        order of ``node_poses`` (docs/CONVENTIONS.md, "Per-node noise").
    prior : GaussianPrior or None
        The Gaussian prior (MAP, default the paper's); None for maximum
        likelihood.
    initial_state : (F, 4) float, optional
        Starting points; default :func:`mmsnap_graph.fusion.problem.initial_states`.
    pose_covariances : (N, 3, 3) float, optional
        Calibration-aware fusion (docs/CONVENTIONS.md): each pose's covariance
        in the Pose2 body tangent, all NaN (or zero) for an exact pose. The
        estimate is unchanged; the covariance adds the poses' by linear
        propagation, ``P = P_x + A Sigma_p A^T``
        (:mod:`~mmsnap_graph.fusion.solvers.vectorized_poses`).
    robust : RobustOptions, "gate", "huber", "cauchy" or None
        Robust fusion, as :func:`mmsnap_graph.fusion.solvers.gtsam_graph.fuse_frame`
        (the same answers): ``"gate"`` tests each node's whitened residual
        3-vector after the fit against ``chi2.ppf(robust.gate_probability,
        3)`` and refits a failing frame without each node in turn;
        ``"huber"`` / ``"cauchy"`` weigh each node by GTSAM's kernel
        (iteratively reweighted least squares, the same minimum and weighted
        covariance as GTSAM's ``noiseModel.Robust``).
    options : FusionOptions
        ``options.lm``: Levenberg-Marquardt's settings; the limit is
        ``lm.max_steps``, steps per frame, rejected ones included (GTSAM's
        limit in ``fuse_frame``, ``lm.max_iterations``, counts outer
        iterations only, each of which may try several damping values, so
        the two limits are not the same number). ``options.step_tolerance``: a frame has converged
        when an accepted step is smaller than ``step_tolerance * (1 + |x|)``
        in every component, or when no step decreases the cost any more
        (then it sits at a minimum to rounding). ``options.newton_after``:
        after this many steps, a frame that has not converged adds the
        second-order residual term to its information matrix (Newton steps,
        where that matrix is positive definite), which turns Gauss-Newton's
        slow linear convergence near weakly observed minima into quadratic
        convergence; the minimum and the Laplace covariance (Gauss-Newton
        information at the minimum) are unchanged. ``options.chunk_size``:
        frames solved together in the first iterations (a size whose
        temporaries stay in cache); the frames that need more iterations are
        then solved together. ``options.covariance`` must be ``"laplace"``.

    Returns
    -------
    BatchResult
        ``status`` holds :class:`~mmsnap_graph.data.results.Status` codes;
        ``rejected`` the nodes left out (gate) or down-weighted (kernels).
        ``success`` implies a finite state and a positive-definite covariance.
    """
    poses, z, obs = validate_frames(node_poses, measurements, observed)
    noise = check_node_noise(noise, z.shape[1])
    pose_cov = check_pose_covariances(pose_covariances, z.shape[1])
    params, max_iterations, chunk_size = _check_options(noise, prior, options)
    robust = robust_options(robust)
    if robust is not None and robust.kernel_pair is not None:
        params = replace(params, kernel=robust.kernel_pair)
    x0 = _start(initial_state, poses, z, obs, prior, noise, chunk_size)
    result = _robust_solve(poses, z, obs, x0, prior, noise, params, max_iterations, chunk_size,
                           robust)
    if pose_cov is None:
        return result
    return _with_pose_covariance(result, poses, obs, params, pose_cov)


def _start(initial_state, poses, z, obs, prior, noise, chunk_size) -> NDArray:
    """The starting states (F, 4): the given ones (checked) or the initial values."""
    if initial_state is None:
        return _initial_states(poses, z, obs, prior, noise, chunk_size)
    x0 = check_finite(as_float_array(initial_state, "initial_state"), "initial_state")
    if x0.shape != (z.shape[0], 4):
        raise ValidationError(f"initial_state must have shape ({z.shape[0]}, 4), got {x0.shape}")
    return np.array(x0, dtype=float)


def _with_pose_covariance(result, poses, obs, params, pose_cov) -> BatchResult:
    """The calibration-aware covariance of the solved frames: the measurements
    kept by the gate, each node weighted as in the kernel fit."""
    kept = obs & ~result.rejected if params.kernel is None else obs
    weights = None
    if params.kernel is not None:
        s2 = np.nan_to_num(node_d2(result.whitened_residuals))
        weights = kernel_weight_and_loss(params.kernel[0], params.kernel[1], s2)[0]
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        cov = propagate_pose_covariance(result.covariance, result.state, poses, kept,
                                        params.inv_sigma, pose_cov, weights)
    cov[~result.success] = np.nan
    return replace(result, covariance=cov)


def _robust_solve(poses, z, obs, x0, prior, noise, params, max_iterations, chunk_size,
                  robust) -> BatchResult:
    """The plain fit, then the gate or the kernel fit started from it."""
    plain = params if params.kernel is None else replace(params, kernel=None)
    result = _solve(poses, z, obs, x0, plain, max_iterations, chunk_size)
    if robust is None:
        return result
    if robust.kernel == "gate":
        return _gate(result, poses, z, obs, prior, noise, params, max_iterations, chunk_size,
                     robust.gate_probability)
    # The kernel fit starts from the plain one (a non-convex kernel from the
    # detections' average can stall in a wrong basin), as fuse_frame.
    start = np.where(result.success[:, None], result.state, x0)
    result = replace(_solve(poses, z, obs, start, params, max_iterations, chunk_size),
                     initial_state=x0)
    return _flag_outlying(result, obs, robust.threshold)


def _check_options(noise, prior, options):
    """Validated solver settings: ``(SolverParams, max_iterations, chunk_size)``;
    ``noise`` the validated per-node tuple."""
    check_prior(prior)
    options = check_options(options)
    if options.covariance != "laplace":
        raise ValidationError(f"fuse_batch returns the Laplace covariance only; "
                              f"options.covariance must be 'laplace', got {options.covariance!r}")
    params = SolverParams(
        inv_sigma=1.0 / node_sigmas(noise),
        prior_mean=None if prior is None else np.asarray(prior.mean, dtype=float),
        prior_inv_sigma=None if prior is None else 1.0 / np.asarray(prior.sigmas, dtype=float),
        step_tolerance=options.step_tolerance,
        newton_after=options.newton_after,
        lm=options.lm,
    )
    return params, options.lm.max_steps, options.chunk_size


def _initial_states(poses, z, obs, prior, noise, chunk_size):
    """:func:`~.problem.initial_states` in chunks (its temporaries then stay in cache)."""
    x0 = np.empty((z.shape[0], 4))
    for start in range(0, z.shape[0], chunk_size):
        sl = slice(start, start + chunk_size)
        x0[sl] = initial_states(poses[sl] if poses.ndim == 3 else poses, z[sl],
                                observed=obs[sl], prior=prior, noise=noise)
    return x0


#: A covariance whose information matrix has ``max diag / min Cholesky
#: pivot^2`` (a lower bound of its condition number) above this is flagged
#: singular: its smallest eigenvalues are lost to rounding.
_MAX_CONDITION = 1e13


def _solve(poses, z, obs, x0, params, max_iterations, chunk_size) -> BatchResult:
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
    # As oneshot.fuse_frame: no covariance for a frame that failed.
    cov[status != _CONVERGED] = np.nan
    return BatchResult(
        state=state,
        covariance=cov,
        success=status == _CONVERGED,
        status=status,
        iterations=iterations,
        final_cost=cost,
        initial_state=x0,
        whitened_residuals=residuals,
        degeneracy=degeneracy,
    )


def _whitened(state, poses, z, weight, params) -> NDArray:
    """Plain whitened residuals (F, N, 3) at ``state`` (zeros where unobserved)."""
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        aug, _ = evaluate(state, poses, z, weight, params.inv_sigma, None, None)
    return aug[:, 4].T.reshape(state.shape[0], -1, 3).copy()


def _flag_outlying(result, obs, threshold) -> BatchResult:
    """A kernel fit's ``rejected``: the nodes whose residual fails the gate."""
    rejected = (node_d2(result.whitened_residuals) > threshold) & obs & result.success[:, None]
    return replace(result, rejected=rejected)


def _gate(result, poses, z, obs, prior, noise, params, max_iterations, chunk_size,
          probability) -> BatchResult:
    """``robust="gate"``: refit each frame whose residuals fail the gate
    without each of its nodes in turn (those with at least two nodes left, so
    that the rest can still be tested); keep the passing refit of lowest cost,
    or flag the frame ``Status.RESIDUAL_TEST_FAILED``."""
    failing = np.flatnonzero(result.success & residual_test_fails(result.whitened_residuals, probability))
    out = {name: np.array(getattr(result, name)) for name in _GATED_FIELDS}
    rejected = np.zeros(obs.shape, dtype=bool)
    if failing.size:
        best, best_cost = np.full(failing.size, -1), np.full(failing.size, np.inf)
        n_pass, refits = np.zeros(failing.size, dtype=np.int64), {}
        for n in range(obs.shape[1]):
            sel = obs[failing, n] & (obs[failing].sum(axis=1) >= 3)
            rows = failing[sel]
            if rows.size == 0:
                continue
            obs_n = obs[rows].copy()
            obs_n[:, n] = False
            p_rows = poses[rows] if poses.ndim == 3 else poses
            x0 = _initial_states(p_rows, z[rows], obs_n, prior, noise, chunk_size)
            sub = _solve(p_rows, z[rows], obs_n, x0, params, max_iterations, chunk_size)
            ok = sub.success & ~residual_test_fails(sub.whitened_residuals, probability)
            n_pass[sel] += ok
            better = ok & (sub.final_cost < best_cost[sel])
            best[np.flatnonzero(sel)[better]] = n
            best_cost[np.flatnonzero(sel)[better]] = sub.final_cost[better]
            refits[n] = (rows, sub)
        best[n_pass != 1] = -1  # none, or ambiguous: which node is the outlier?
        for n, (rows, sub) in refits.items():
            take = best[np.searchsorted(failing, rows)] == n
            for name in _GATED_FIELDS:
                out[name][rows[take]] = getattr(sub, name)[take]
            rejected[rows[take], n] = True
        fixed = failing[best >= 0]
        full = np.zeros((0, obs.shape[1], 3)) if fixed.size == 0 else _whitened(out["state"][fixed], poses[fixed] if poses.ndim == 3 else poses, z[fixed],
                         obs[fixed].astype(float), params)
        full[~obs[fixed]] = np.nan
        out["whitened_residuals"][fixed] = full
        lost = failing[best < 0]
        out["status"][lost] = Status.RESIDUAL_TEST_FAILED
        out["covariance"][lost] = np.nan
    return replace(result, **out, success=out["status"] == _CONVERGED, rejected=rejected)

#: The per-frame fields a gate refit replaces.
_GATED_FIELDS = ("state", "covariance", "status", "iterations", "final_cost", "initial_state",
                 "whitened_residuals", "degeneracy")


# ---------------------------------------------------------------------------
# The solve contract


def solve_frames(problem, options: FusionOptions = DEFAULT_OPTIONS):
    """Every frame of a :class:`~mmsnap_graph.fusion.frame_problem.FrameProblem`
    solved together (Levenberg-Marquardt vectorized over the frames): a
    :class:`~mmsnap_graph.data.solution.FusionSolution` with the Laplace
    covariance (:func:`mmsnap_graph.fusion.solve.solve`)."""
    prior = problem.prior
    params = SolverParams(
        inv_sigma=1.0 / problem.sigmas,
        prior_mean=None if prior is None else np.asarray(prior.mean, dtype=float),
        prior_inv_sigma=None if prior is None else 1.0 / np.asarray(prior.sigmas, dtype=float),
        step_tolerance=options.step_tolerance, newton_after=options.newton_after,
        kernel=problem.kernel, lm=options.lm)
    x0 = initial_states(problem)
    res = _solve(problem.poses, problem.measurements, problem.observed, x0, params,
                 options.lm.max_steps, options.chunk_size)
    if problem.pose_covariances is not None:
        res = _with_pose_covariance(res, problem.poses, problem.observed, params,
                                    problem.pose_covariances)
    return FusionSolution(state=res.state, covariance=res.covariance, status=res.status,
                          iterations=res.iterations, final_cost=res.final_cost,
                          initial_state=x0, whitened_residuals=res.whitened_residuals,
                          degeneracy=res.degeneracy)
