"""Vectorized one-shot fusion of many frames at once (docs/CONVENTIONS.md, "One-shot fusion").

The per-frame GTSAM solve (:func:`mmsnap_graph.fusion.oneshot.fuse_frame`) costs a
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

from dataclasses import dataclass, replace
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from factors.models import measurement_model, wrap_angle

from ..errors import ValidationError
from .._linalg import chol_soa, cholesky4, cholesky4_inverse, cholesky4_solve, from_soa, inverse_soa, solve_soa
from .._validation import as_float_array, check_finite
from ..data.noise import GaussianPrior, MeasurementNoise
from ..data.results import BatchResult, Status
from .problem import check_count, check_noise, check_prior, initial_states, validate_frames, velocity_degeneracy
from .robust import (
    RESIDUAL_GATE_PROBABILITY,
    check_robust,
    check_robust_k,
    kernel_weight_and_loss,
    node_d2,
    residual_gate_threshold,
    residual_test_fails,
)

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

# Steps a frame reuses the finite-difference curvature of its Newton steps.
_CURVATURE_REFRESH = 3

# A chunk of the first stage stops when fewer than 1/16 of its frames are
# still running (the rest continue in the second stage, all chunks together).
_STAGE1_MIN_LIVE_FRACTION = 16

# Iterations of the chunked first stage (most frames converge within them).
_STAGE1_ITERATIONS = 8


def _evaluate(state, poses, z, weight, inv_sigma, prior_mean, prior_inv_sigma, kernel=None):
    """Whitened Jacobian and residuals at ``state (F, 4)``, and the cost.

    poses : (N, 3) or (F, N, 3). Returns ``aug (3 N, 5, F)``, frames last
    (each entry a contiguous array over frames): for measurement row ``m``
    (node ``m // 3``, component ``m % 3``), ``aug[m, :4]`` is the whitened
    Jacobian ``d r_m / d state`` and ``aug[m, 4]`` the whitened residual
    ``r_m = (h - z) / sigma``, all zero for unobserved nodes; and
    ``cost (F,)``, GTSAM's ``0.5 * sum r^2`` with the prior included. The
    model is called once per node with a (F, 4) state.

    ``kernel`` ``(name, k)`` (Huber or Cauchy on each node's whitened
    3-vector, as GTSAM's ``noiseModel.Robust``): each node's rows are scaled
    by the square root of its weight (iteratively reweighted least squares)
    and ``cost`` is the kernel's loss, GTSAM's error of the robust graph.
    """
    f, n_nodes = z.shape[:2]
    aug = np.empty((3 * n_nodes, 5, f))
    for n in range(n_nodes):
        h, jac = measurement_model(state, poses[..., n, :])
        e = h - z[:, n]
        e[:, 1] = wrap_angle(e[:, 1])
        seen = weight[:, n] > 0
        partial = not seen.all()
        rows = slice(3 * n, 3 * n + 3)
        w = inv_sigma[:, None] * weight[:, n] if partial else inv_sigma[:, None]  # (3, F) or (3, 1)
        np.multiply(jac.transpose(1, 2, 0), w[:, None, :], out=aug[rows, :4])
        np.multiply(e.T, w, out=aug[rows, 4])
        if partial:
            # An unobserved node contributes exactly nothing, even where its
            # model is undefined (a state on that node gives 0 * NaN).
            aug[3 * n:3 * n + 3, :, ~seen] = 0.0
    if kernel is None:
        r = aug[:, 4]
        cost = 0.5 * np.einsum("mf,mf->f", r, r)
    else:
        cost = _reweight(aug, kernel)
    if prior_mean is not None:
        dp = (state - prior_mean) * prior_inv_sigma
        cost += 0.5 * np.einsum("fk,fk->f", dp, dp)
    return aug, cost


def _reweight(aug, kernel):
    """Scale each node's rows of ``aug`` by the square root of its kernel
    weight; return the summed kernel loss (F,)."""
    name, k = kernel
    r = aug[:, 4]
    s2 = (r * r).reshape(-1, 3, r.shape[-1]).sum(axis=1)  # (N, F)
    weight, loss = kernel_weight_and_loss(name, k, s2)
    aug *= np.repeat(np.sqrt(weight), 3, axis=0)[:, None, :]
    return loss.sum(axis=0)


def _normal_equations(state, aug, prior_mean, prior_inv_sigma):
    """Information ``H (4, 4, F)`` and gradient ``g (4, F)`` (frames last),
    entry by entry as sums over the measurement rows of ``aug``."""
    f = aug.shape[-1]
    info = np.empty((4, 4, f))
    grad = np.empty((4, f))
    for i in range(4):
        col_i = aug[:, i]
        for j in range(i + 1):
            v = np.einsum("mf,mf->f", col_i, aug[:, j])
            info[i, j] = v
            if i != j:
                info[j, i] = v
        grad[i] = np.einsum("mf,mf->f", col_i, aug[:, 4])
    if prior_mean is not None:
        p2 = prior_inv_sigma**2
        for i in range(4):
            info[i, i] += p2[i]
        grad += ((state - prior_mean) * p2).T
    return info, grad


def _residual_curvature(state, poses, z, weight, inv_sigma, aug, kernel=None):
    """The second-order term ``S = sum_m r_m d^2 r_m / dx^2``, (4, 4, F), that
    Gauss-Newton drops, by forward differences of the model's Jacobian.

    Near a minimum with sizeable residuals along a weakly observed direction
    (a target near the line through two radars) Gauss-Newton converges only
    linearly, sometimes with a rate close to one; adding ``S`` gives Newton's
    quadratic convergence to the same minimum. The prior is quadratic and has
    no such term.
    """
    f = state.shape[0]
    r = aug[:, 4]
    curv = np.empty((4, 4, f))
    for k in range(4):
        eps = 1e-7 * (1.0 + np.abs(state[:, k]))
        shifted = state.copy()
        shifted[:, k] += eps
        aug_k, _ = _evaluate(shifted, poses, z, weight, inv_sigma, None, None, kernel)
        diff = aug_k[:, :4] - aug[:, :4]
        curv[k] = np.einsum("mf,mjf->jf", r, diff) / eps
    return 0.5 * (curv + curv.transpose(1, 0, 2))


def fuse_batch(
    node_poses: ArrayLike,
    measurements: ArrayLike,
    *,
    observed: ArrayLike | None = None,
    noise: MeasurementNoise = MeasurementNoise(),
    prior: GaussianPrior | None = GaussianPrior(),
    initial_state: ArrayLike | None = None,
    max_iterations: int = 200,
    step_tolerance: float = 1e-10,
    newton_after: int = 10,
    chunk_size: int = 8192,
    robust: Literal["gate", "huber", "cauchy"] | None = None,
    robust_k: float | None = None,
    residual_gate_probability: float = RESIDUAL_GATE_PROBABILITY,
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
    noise : MeasurementNoise
        Measurement sigmas (default: the paper's).
    prior : GaussianPrior or None
        The Gaussian prior (MAP, default the paper's); None for maximum
        likelihood.
    initial_state : (F, 4) float, optional
        Starting points; default :func:`mmsnap_graph.fusion.problem.initial_states`.
    max_iterations : int
        Levenberg-Marquardt steps per frame, rejected ones included. GTSAM's
        limit in ``fuse_frame`` counts outer iterations only, each of which
        may try several damping values, so the two limits are not the same
        number.
    step_tolerance : float
        A frame has converged when an accepted step is smaller than
        ``step_tolerance * (1 + |x|)`` in every component, or when no step
        decreases the cost any more (then it sits at a minimum to rounding).
    newton_after : int
        After this many steps, a frame that has not converged adds the
        second-order residual term to its information matrix (Newton steps,
        where that matrix is positive definite), which turns Gauss-Newton's
        slow linear convergence near weakly observed minima into quadratic
        convergence. The minimum and the Laplace covariance (Gauss-Newton
        information at the minimum) are unchanged.
    chunk_size : int
        Frames solved together in the first iterations (a size whose
        temporaries stay in cache); the frames that need more iterations are
        then solved together.
    robust : {"gate", "huber", "cauchy"} or None
        Robust fusion, as :func:`mmsnap_graph.fusion.oneshot.fuse_frame`
        (the same answers): ``"gate"`` tests each node's whitened residual
        3-vector after the fit against ``chi2.ppf(residual_gate_probability,
        3)`` and refits a failing frame without each node in turn;
        ``"huber"`` / ``"cauchy"`` weigh each node by GTSAM's kernel
        (iteratively reweighted least squares, the same minimum and weighted
        covariance as GTSAM's ``noiseModel.Robust``).
    robust_k : float, optional
        The kernel's constant on the whitened norm (default
        :data:`factors.robust.ROBUST_K_DEFAULT`).
    residual_gate_probability : float
        The gate's probability (default
        :data:`~.problem.RESIDUAL_GATE_PROBABILITY`).

    Returns
    -------
    BatchResult
        ``status`` holds :class:`~mmsnap_graph.data.results.Status` codes;
        ``rejected`` the nodes left out (gate) or down-weighted (kernels).
        ``success`` implies a finite state and a positive-definite covariance.
    """
    poses, z, obs = validate_frames(node_poses, measurements, observed)
    params, max_iterations, chunk_size = _check_options(
        noise, prior, max_iterations, step_tolerance, newton_after, chunk_size)
    robust = check_robust(robust)
    threshold = residual_gate_threshold(residual_gate_probability)
    if robust in ("huber", "cauchy"):
        params = replace(params, kernel=(robust, check_robust_k(robust, robust_k)))
    if initial_state is None:
        x0 = _initial_states(poses, z, obs, prior, noise, chunk_size)
    else:
        x0 = check_finite(as_float_array(initial_state, "initial_state"), "initial_state")
        if x0.shape != (z.shape[0], 4):
            raise ValidationError(f"initial_state must have shape ({z.shape[0]}, 4), got {x0.shape}")
        x0 = np.array(x0, dtype=float)
    return _robust_solve(poses, z, obs, x0, prior, noise, params, max_iterations, chunk_size,
                         robust, threshold, residual_gate_probability)


def _robust_solve(poses, z, obs, x0, prior, noise, params, max_iterations, chunk_size,
                  robust, threshold, probability) -> BatchResult:
    """The plain fit, then the gate or the kernel fit started from it."""
    plain = params if params.kernel is None else replace(params, kernel=None)
    result = _solve(poses, z, obs, x0, plain, max_iterations, chunk_size)
    if robust is None:
        return result
    if robust == "gate":
        return _gate(result, poses, z, obs, prior, noise, params, max_iterations, chunk_size,
                     probability)
    # The kernel fit starts from the plain one (a non-convex kernel from the
    # detections' average can stall in a wrong basin), as fuse_frame.
    start = np.where(result.success[:, None], result.state, x0)
    result = replace(_solve(poses, z, obs, start, params, max_iterations, chunk_size),
                     initial_state=x0)
    return _flag_outlying(result, obs, threshold)


@dataclass(frozen=True, slots=True)
class _Params:
    inv_sigma: NDArray
    prior_mean: NDArray | None
    prior_inv_sigma: NDArray | None
    step_tolerance: float
    newton_after: int
    kernel: tuple | None = None


def _check_options(noise, prior, max_iterations, step_tolerance, newton_after, chunk_size):
    """Validated solver settings: ``(_Params, max_iterations, chunk_size)``."""
    check_noise(noise)
    check_prior(prior)
    max_iterations = check_count(max_iterations, "max_iterations")
    chunk_size = check_count(chunk_size, "chunk_size")
    newton_after = check_count(newton_after, "newton_after", 0)
    if isinstance(step_tolerance, (bool, np.bool_)) or not isinstance(
            step_tolerance, (int, float, np.integer, np.floating)):
        raise ValidationError(f"step_tolerance must be a number, got {step_tolerance!r}")
    if not (np.isfinite(step_tolerance) and step_tolerance > 0):
        raise ValidationError(f"step_tolerance must be finite and > 0, got {step_tolerance!r}")
    params = _Params(
        inv_sigma=1.0 / np.asarray(noise.sigmas, dtype=float),
        prior_mean=None if prior is None else np.asarray(prior.mean, dtype=float),
        prior_inv_sigma=None if prior is None else 1.0 / np.asarray(prior.sigmas, dtype=float),
        step_tolerance=float(step_tolerance),
        newton_after=newton_after,
    )
    return params, max_iterations, chunk_size


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
    empty = ~obs.any(axis=1) if params.prior_mean is None else np.zeros(n_frames, dtype=bool)
    state[empty] = x0[empty]

    def run(rows, x_start, it_start, budget, min_live=0):
        if rows.size == 0:
            return
        p_rows = poses[rows] if poses.ndim == 3 else poses
        out = _lm(x_start, p_rows, z[rows], weight[rows], params, it_start, budget, min_live)
        state[rows], cost[rows], residuals[rows], info[:, :, rows], iterations[rows], status[rows] = out

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
            run(left, state[left].copy(), iterations[left].copy(), max_iterations)

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
        aug, _ = _evaluate(state, poses, z, weight, params.inv_sigma, None, None)
    return aug[:, 4].T.reshape(state.shape[0], -1, 3).copy()


def _flag_outlying(result, obs, threshold) -> BatchResult:
    """A kernel fit's ``rejected``: the nodes whose residual fails the gate."""
    rejected = (node_d2(result.whitened_residuals) > threshold) & obs & result.success[:, None]
    return replace(result, rejected=rejected)


class _Frames:
    """The frames of one :func:`_lm` call: the output arrays (indexed by frame)
    and the active set (arrays with an ``_a`` suffix, indexed by ``idx``)."""

    def __init__(self, x0, poses, z, weight, params, it_start):
        n_frames, n_nodes = z.shape[:2]
        self.n_nodes = n_nodes
        self.per_frame_poses = poses.ndim == 3
        self.state = np.empty((n_frames, 4))
        self.cost = np.empty(n_frames)
        self.residuals = np.empty((n_frames, n_nodes, 3))
        self.info_out = np.empty((4, 4, n_frames))
        self.iterations = np.empty(n_frames, dtype=np.int64)
        self.status = np.empty(n_frames, dtype=np.int8)
        self.idx = np.arange(n_frames)
        self.p_a, self.z_a, self.w_a, self.x_a = poses, z, weight, x0
        self.aug_a, self.c_a = _evaluate(x0, poses, z, weight, params.inv_sigma,
                                         params.prior_mean, params.prior_inv_sigma, params.kernel)
        self.lam_a = np.full(n_frames, 1e-5)
        self.nu_a = np.full(n_frames, 2.0)
        self.it_a = np.array(it_start, dtype=np.int64)
        self.small_a = np.zeros(n_frames, dtype=bool)
        self.live = np.ones(n_frames, dtype=bool)
        # The curvature term of the Newton steps and its age in steps: finite
        # differences cost four model evaluations, so a frame reuses its term
        # for a few steps (near the minimum it hardly changes).
        self.curv_a = np.zeros((4, 4, n_frames))
        self.curv_age = np.full(n_frames, _CURVATURE_REFRESH)
        self.info = self.grad = None

    def finish(self, sel, code):
        """Write the frames ``sel`` (a mask over the active set) out."""
        out = self.idx[sel]
        self.state[out] = self.x_a[sel]
        self.cost[out] = self.c_a[sel]
        self.residuals[out] = self.aug_a[:, 4, sel].T.reshape(-1, self.n_nodes, 3)
        self.iterations[out] = self.it_a[sel]
        self.status[out] = code
        self.info_out[:, :, out] = self.info[:, :, sel]
        self.live[sel] = False

    def compact(self):
        """Drop the finished frames from the active set."""
        keep = self.live
        self.idx = self.idx[keep]
        if self.per_frame_poses:
            self.p_a = self.p_a[keep]
        self.z_a, self.w_a, self.x_a = self.z_a[keep], self.w_a[keep], self.x_a[keep]
        self.c_a, self.aug_a = self.c_a[keep], self.aug_a[..., keep]
        self.lam_a, self.nu_a, self.it_a = self.lam_a[keep], self.nu_a[keep], self.it_a[keep]
        self.curv_a, self.curv_age = self.curv_a[:, :, keep], self.curv_age[keep]
        self.info, self.grad = self.info[:, :, keep], self.grad[:, keep]
        self.live = np.ones(self.idx.size, dtype=bool)

    def outputs(self):
        return self.state, self.cost, self.residuals, self.info_out, self.iterations, self.status


def _lm(x0, poses, z, weight, params, it_start, max_iterations, min_live=0):
    """Levenberg-Marquardt over the frames of ``x0 (F, 4)``.

    Returns ``state (F, 4)``, ``cost (F,)``, ``residuals (F, N, 3)``,
    ``info (4, 4, F)`` (undamped information at the returned state),
    ``iterations (F,)`` (counting from ``it_start``) and ``status (F,)``;
    frames still running after ``max_iterations`` have status ``_MAX_ITER``.
    """
    fr = _Frames(x0, poses, z, weight, params, it_start)
    while True:
        fr.info, fr.grad = _normal_equations(fr.x_a, fr.aug_a, params.prior_mean, params.prior_inv_sigma)
        if not _retire(fr, max_iterations, min_live):
            break
        step_t, ok, decrement, damping = _damped_step(fr, params)
        # The reduction of the cost that the local quadratic model predicts;
        # s^T M s = decrement - lambda s^T D s, since (M + lambda D) s = -g.
        predicted = 0.5 * (decrement + np.einsum("if,if->f", damping, step_t * step_t))
        # At a minimum the best possible decrease (the Newton decrement, when
        # the damping is light) is below the rounding of the cost itself.
        flat = fr.live & ok & (fr.lam_a <= 1e-2) & (decrement <= 1e-16 * np.maximum(fr.c_a, 1.0))
        if np.any(flat):
            fr.finish(flat, _CONVERGED)
            if not np.any(fr.live):
                break
        _try_step(fr, params, step_t, ok, predicted)
    return fr.outputs()


def _retire(fr: _Frames, max_iterations, min_live) -> bool:
    """Finish the frames that are done; False when none is left to iterate."""
    live = fr.live
    # A non-finite state gives a non-finite cost (every frame here has a
    # measurement or a prior).
    bad = live & ~np.isfinite(fr.c_a)
    if np.any(bad):
        fr.finish(bad, _NONFINITE)
    if np.any(fr.small_a & live):
        # The last accepted step was below tolerance.
        fr.finish(fr.small_a & live, _CONVERGED)
    if np.any(live & (fr.it_a >= max_iterations)):
        fr.finish(live & (fr.it_a >= max_iterations), _MAX_ITER)
    n_live = int(np.count_nonzero(live))
    if n_live == 0:
        return False
    if n_live < min_live:
        # Too few frames left for numpy to pay: hand them on (stage 2).
        fr.finish(live.copy(), _MAX_ITER)
        return False
    if n_live < 0.75 * live.size:
        # Compact the active set when enough frames are done.
        fr.compact()
    return True


_DIAG = np.arange(4)


def _damped_step(fr: _Frames, params):
    """The damped (Gauss-)Newton step of every active frame:
    ``(step (4, F), factorized (F,), decrement (F,), damping (4, F))``."""
    model = fr.info
    slow = np.flatnonzero(fr.live & (fr.it_a >= params.newton_after))
    if slow.size:
        need = slow[fr.curv_age[slow] >= _CURVATURE_REFRESH]
        if need.size:
            pp = fr.p_a[need] if fr.per_frame_poses else fr.p_a
            fr.curv_a[:, :, need] = _residual_curvature(fr.x_a[need], pp, fr.z_a[need], fr.w_a[need],
                                                        params.inv_sigma, fr.aug_a[..., need],
                                                        params.kernel)
            fr.curv_age[need] = 0
        fr.curv_age[slow] += 1
        newton = fr.info[:, :, slow] + fr.curv_a[:, :, slow]
        # Newton only where its model is convex; elsewhere Gauss-Newton.
        use = chol_soa(newton)[1]
        model = fr.info.copy()
        model[:, :, slow[use]] = newton[:, :, use]
    diag = model[_DIAG, _DIAG]
    # Marquardt damping on the diagonal, floored so that an unobservable
    # direction (zero diagonal) is still damped.
    floor = 1e-15 * np.maximum(np.abs(diag).max(axis=0), 1e-300)
    damped = model.copy()
    damping = fr.lam_a * np.maximum(diag, floor)
    damped[_DIAG, _DIAG] += damping
    lo, ok = chol_soa(damped)
    step_t = solve_soa(lo, fr.grad)
    step_t *= -1.0
    decrement = -np.einsum("if,if->f", fr.grad, step_t)
    return step_t, ok, decrement, damping


def _try_step(fr: _Frames, params, step_t, ok, predicted) -> None:
    """Evaluate the step; accept or reject it per frame and update the damping."""
    live = fr.live
    x_a, c_a = fr.x_a, fr.c_a
    x_new = x_a + step_t.T
    aug_n, c_n = _evaluate(x_new, fr.p_a, fr.z_a, fr.w_a, params.inv_sigma,
                           params.prior_mean, params.prior_inv_sigma, params.kernel)
    fr.it_a += live
    accept = live & ok & (c_n <= c_a)  # False for a NaN cost
    fr.small_a = accept & np.all(np.abs(step_t) <= params.step_tolerance * (1.0 + np.abs(x_a.T)), axis=0)
    # Nielsen's damping update from the gain ratio actual / predicted.
    with np.errstate(divide="ignore", invalid="ignore"):
        gain = (c_a - c_n) / predicted
    gain = np.where(np.isfinite(gain), gain, 0.0)
    shrink = np.maximum(1.0 / 3.0, 1.0 - (2.0 * gain - 1.0) ** 3)
    fr.lam_a = np.where(accept, np.maximum(fr.lam_a * shrink, 1e-12), np.minimum(fr.lam_a * fr.nu_a, 1e12))
    fr.nu_a = np.where(accept, 2.0, fr.nu_a * 2.0)
    rejected = ~accept
    if np.any(rejected):
        np.copyto(x_new, x_a, where=rejected[:, None])
        np.copyto(c_n, c_a, where=rejected)
        np.copyto(aug_n, fr.aug_a, where=rejected)
    fr.x_a, fr.c_a, fr.aug_a = x_new, c_n, aug_n
    # A frame whose damping has grown without bound cannot move: it sits
    # at a minimum to rounding (typical when the cost is flat).
    fr.small_a |= live & (fr.lam_a >= 1e12)


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
