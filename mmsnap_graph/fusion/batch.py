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
(:func:`mmsnap_graph.fusion.oneshot.initial_state`'s vectorized core) and returns the
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

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from factors.models import measurement_model, wrap_angle

from ..errors import ValidationError
from .._linalg import chol_soa, cholesky4, cholesky4_inverse, cholesky4_solve, from_soa, inverse_soa, solve_soa
from .._validation import as_float_array, check_finite

__all__ = [
    "STATUS_MESSAGES",
    "velocity_degeneracy",
    "BatchResult",
    "fuse_batch",
    "cholesky4",
    "cholesky4_solve",
    "cholesky4_inverse",
]

#: Meaning of :attr:`BatchResult.status` codes.
STATUS_MESSAGES = {
    0: "converged",
    1: "maximum number of iterations reached",
    2: "information matrix is not positive definite at the solution",
    3: "non-finite cost or state",
    4: "no measurement and no prior",
}
_CONVERGED, _MAX_ITER, _SINGULAR, _NONFINITE, _EMPTY = range(5)


# Steps a frame reuses the finite-difference curvature of its Newton steps.
_CURVATURE_REFRESH = 3

# A chunk of the first stage stops when fewer than 1/16 of its frames are
# still running (the rest continue in the second stage, all chunks together).
_STAGE1_MIN_LIVE_FRACTION = 16

# Iterations of the chunked first stage (most frames converge within them).
_STAGE1_ITERATIONS = 8


@dataclass(frozen=True, kw_only=True, slots=True)
class BatchResult:
    """One-shot fusion of ``F`` frames.

    state : (F, 4) ``(x_m, y_m, vx_mps, vy_mps)``, global frame.
    covariance : (F, 4, 4) Laplace covariance (NaN where ``success`` is False).
    success : (F,) bool; status : (F,) int, a key of :data:`STATUS_MESSAGES`.
    iterations : (F,) int, accepted plus rejected LM steps.
    final_cost : (F,) ``0.5 * sum of squared whitened residuals`` (GTSAM's
        graph error), prior included for MAP.
    initial_state : (F, 4) the starting point.
    whitened_residuals : (F, N, 3) ``(h - z) / sigma`` at the solution
        (spatial frequency wrapped), NaN rows for unobserved nodes.
    degeneracy : (F,) condition number of the lines of sight's velocity
        information (``FusionResult.degeneracy``; inf for parallel lines of
        sight or a single node).
    """

    state: NDArray
    covariance: NDArray
    success: NDArray
    status: NDArray
    iterations: NDArray
    final_cost: NDArray
    initial_state: NDArray
    whitened_residuals: NDArray
    degeneracy: NDArray

    def __len__(self) -> int:
        return int(self.state.shape[0])

    def message(self, frame_index: int) -> str:
        """The status message of one frame."""
        return STATUS_MESSAGES[int(self.status[frame_index])]


def _check_inputs(node_poses, measurements, observed):
    z = check_finite(as_float_array(measurements, "measurements"), "measurements")
    if z.ndim != 3 or z.shape[-1] != 3:
        raise ValidationError(f"measurements must have shape (F, N, 3), got {z.shape}")
    n_frames, n_nodes = z.shape[:2]
    poses = check_finite(as_float_array(node_poses, "node_poses"), "node_poses")
    if poses.shape not in ((n_nodes, 3), (n_frames, n_nodes, 3)):
        raise ValidationError(
            f"node_poses must have shape ({n_nodes}, 3) or ({n_frames}, {n_nodes}, 3), "
            f"got {poses.shape}"
        )
    if observed is None:
        obs = np.ones((n_frames, n_nodes), dtype=bool)
    else:
        obs = np.asarray(observed)
        if obs.shape != (n_frames, n_nodes) or obs.dtype != bool:
            raise ValidationError(
                f"observed must be a bool array of shape ({n_frames}, {n_nodes}), "
                f"got {obs.dtype} {obs.shape}"
            )
    return poses, z, obs


def _evaluate(state, poses, z, weight, inv_sigma, prior_mean, prior_inv_sigma):
    """Whitened Jacobian and residuals at ``state (F, 4)``, and the cost.

    poses : (N, 3) or (F, N, 3). Returns ``aug (3 N, 5, F)``, frames last
    (each entry a contiguous array over frames): for measurement row ``m``
    (node ``m // 3``, component ``m % 3``), ``aug[m, :4]`` is the whitened
    Jacobian ``d r_m / d state`` and ``aug[m, 4]`` the whitened residual
    ``r_m = (h - z) / sigma``, all zero for unobserved nodes; and
    ``cost (F,)``, GTSAM's ``0.5 * sum r^2`` with the prior included. The
    model is called once per node with a (F, 4) state.
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
    r = aug[:, 4]
    cost = 0.5 * np.einsum("mf,mf->f", r, r)
    if prior_mean is not None:
        dp = (state - prior_mean) * prior_inv_sigma
        cost += 0.5 * np.einsum("fk,fk->f", dp, dp)
    return aug, cost


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


def _residual_curvature(state, poses, z, weight, inv_sigma, aug):
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
        aug_k, _ = _evaluate(shifted, poses, z, weight, inv_sigma, None, None)
        diff = aug_k[:, :4] - aug[:, :4]
        curv[k] = np.einsum("mf,mjf->jf", r, diff) / eps
    return 0.5 * (curv + curv.transpose(1, 0, 2))


def fuse_batch(
    node_poses: ArrayLike,
    measurements: ArrayLike,
    *,
    observed: ArrayLike | None = None,
    noise=None,
    prior="default",
    initial_state: ArrayLike | None = None,
    max_iterations: int = 200,
    step_tolerance: float = 1e-10,
    newton_after: int = 10,
    chunk_size: int = 8192,
) -> BatchResult:
    """Fuse ``F`` frames of ``N`` nodes' measurements at once (MAP or ML).

    Parameters
    ----------
    node_poses : (N, 3) or (F, N, 3) float
        Node poses ``(x_m, y_m, phi_rad)`` in the global frame.
    measurements : (F, N, 3) float
        ``(range_m, omega_rad, doppler_mps)`` of each node at each frame
        (any finite value where not observed).
    observed : (F, N) bool, optional
        Which nodes see the target at each frame (default: all).
    noise : mmsnap_graph.fusion.oneshot.MeasurementNoise, optional
        Measurement sigmas (default: the paper's).
    prior : mmsnap_graph.fusion.oneshot.GaussianPrior or None
        ``"default"`` uses ``GaussianPrior()`` (MAP, the paper's prior);
        ``None`` is maximum likelihood.
    initial_state : (F, 4) float, optional
        Starting points; default :func:`mmsnap_graph.fusion.oneshot.initial_states`
        (the vectorized core of ``oneshot.initial_state``).
    max_iterations : int
        Levenberg-Marquardt steps per frame, rejected ones included (GTSAM's
        limit, 100 in ``fuse_frame``, counts outer iterations only, each of
        which may try several damping values: 200 here is comparable).
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

    Returns
    -------
    BatchResult
    """
    poses, z, obs = _check_inputs(node_poses, measurements, observed)
    if noise is None:
        from .oneshot import MeasurementNoise

        noise = MeasurementNoise()
    if isinstance(prior, str):
        if prior != "default":
            raise ValidationError(f"prior must be a GaussianPrior, None or 'default', got {prior!r}")
        from .oneshot import GaussianPrior

        prior = GaussianPrior()
    if int(max_iterations) < 1:
        raise ValidationError(f"max_iterations must be >= 1, got {max_iterations!r}")
    if int(chunk_size) < 1:
        raise ValidationError(f"chunk_size must be >= 1, got {chunk_size!r}")
    chunk_size = int(chunk_size)
    if not (np.isfinite(step_tolerance) and step_tolerance > 0):
        raise ValidationError(f"step_tolerance must be finite and > 0, got {step_tolerance!r}")
    n_frames, n_nodes = z.shape[:2]
    inv_sigma = 1.0 / np.asarray(noise.sigmas, dtype=float)
    if prior is None:
        prior_mean = prior_inv_sigma = None
    else:
        prior_mean = np.asarray(prior.mean, dtype=float)
        prior_inv_sigma = 1.0 / np.asarray(prior.sigmas, dtype=float)

    if initial_state is None:
        from . import oneshot

        # In chunks: the initializer's temporaries then stay in cache.
        x0 = np.empty((n_frames, 4))
        for start in range(0, n_frames, chunk_size):
            sl = slice(start, start + chunk_size)
            x0[sl] = oneshot.initial_states(poses[sl] if poses.ndim == 3 else poses, z[sl],
                                            observed=obs[sl], prior=prior, noise=noise)
    else:
        x0 = check_finite(as_float_array(initial_state, "initial_state"), "initial_state")
        if x0.shape != (n_frames, 4):
            raise ValidationError(f"initial_state must have shape ({n_frames}, 4), got {x0.shape}")
    x0 = np.array(x0, dtype=float)

    weight = obs.astype(float)
    params = _Params(
        inv_sigma=inv_sigma,
        prior_mean=prior_mean,
        prior_inv_sigma=prior_inv_sigma,
        step_tolerance=float(step_tolerance),
        newton_after=int(newton_after),
    )
    state = np.empty((n_frames, 4))
    cost = np.full(n_frames, np.nan)
    residuals = np.zeros((n_frames, n_nodes, 3))
    info = np.full((4, 4, n_frames), np.nan)
    iterations = np.zeros(n_frames, dtype=np.int64)
    status = np.full(n_frames, _EMPTY, dtype=np.int8)
    empty = ~obs.any(axis=1) if prior is None else np.zeros(n_frames, dtype=bool)
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
        first = min(_STAGE1_ITERATIONS, int(max_iterations))
        for start in range(0, rows_all.size, chunk_size):
            rows = rows_all[start:start + chunk_size]
            run(rows, x0[rows], np.zeros(rows.size, dtype=np.int64), first,
                max(1, rows.size // _STAGE1_MIN_LIVE_FRACTION))
        left = rows_all[status[rows_all] == _MAX_ITER]
        if left.size and int(max_iterations) > first:
            run(left, state[left].copy(), iterations[left].copy(), int(max_iterations))

        # Laplace covariance: inverse of the undamped information at the solution.
        lo, pd = chol_soa(info)
        cov = from_soa(inverse_soa(lo))
        degeneracy = velocity_degeneracy(state, poses, obs)
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


def velocity_degeneracy(state: ArrayLike, node_poses: ArrayLike, observed: ArrayLike) -> NDArray:
    """Condition number of ``sum_i u_i u_i^T`` over the observed nodes' lines
    of sight, per frame (the vectorized :func:`mmsnap_graph.fusion.oneshot.velocity_degeneracy`;
    see ``FusionResult.degeneracy``). ``inf`` when singular (parallel lines of
    sight, a single node). No validation.

    state : (F, 4); node_poses : (N, 3) or (F, N, 3); observed : (F, N) bool.
    Returns (F,).
    """
    state = np.asarray(state, dtype=float)
    poses = np.asarray(node_poses, dtype=float)
    d = state[:, None, :2] - poses[..., :2]
    r2 = np.sum(d * d, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        w = np.where(np.asarray(observed, dtype=bool), 1.0 / r2, 0.0)
    a11 = np.sum(w * d[..., 0] ** 2, axis=1)
    a12 = np.sum(w * d[..., 0] * d[..., 1], axis=1)
    a22 = np.sum(w * d[..., 1] ** 2, axis=1)
    half_tr = 0.5 * (a11 + a22)
    disc = np.sqrt(0.25 * (a11 - a22) ** 2 + a12 * a12)
    hi = half_tr + disc
    lo = half_tr - disc
    with np.errstate(invalid="ignore", divide="ignore"):
        cond = hi / lo
    singular = ~(hi > 0) | (lo <= hi * 1e-15) | ~np.isfinite(cond)
    return np.where(singular, np.inf, cond)


@dataclass(frozen=True, slots=True)
class _Params:
    inv_sigma: NDArray
    prior_mean: NDArray | None
    prior_inv_sigma: NDArray | None
    step_tolerance: float
    newton_after: int


def _lm(x0, poses, z, weight, params, it_start, max_iterations, min_live=0):
    """Levenberg-Marquardt over the frames of ``x0 (F, 4)``.

    Returns ``state (F, 4)``, ``cost (F,)``, ``residuals (F, N, 3)``,
    ``info (4, 4, F)`` (undamped information at the returned state),
    ``iterations (F,)`` (counting from ``it_start``) and ``status (F,)``;
    frames still running after ``max_iterations`` have status ``_MAX_ITER``.
    """
    inv_sigma, prior_mean, prior_inv_sigma = params.inv_sigma, params.prior_mean, params.prior_inv_sigma
    n_frames, n_nodes = z.shape[:2]
    per_frame_poses = poses.ndim == 3
    state = np.empty((n_frames, 4))
    cost = np.empty(n_frames)
    residuals = np.empty((n_frames, n_nodes, 3))
    info_out = np.empty((4, 4, n_frames))
    iterations = np.empty(n_frames, dtype=np.int64)
    status = np.empty(n_frames, dtype=np.int8)

    # Active frames; arrays with an ``_a`` suffix are indexed by ``idx``.
    idx = np.arange(n_frames)
    p_a, z_a, w_a, x_a = poses, z, weight, x0
    aug_a, c_a = _evaluate(x_a, p_a, z_a, w_a, inv_sigma, prior_mean, prior_inv_sigma)
    lam_a = np.full(n_frames, 1e-5)
    nu_a = np.full(n_frames, 2.0)
    it_a = np.array(it_start, dtype=np.int64)
    small_a = np.zeros(n_frames, dtype=bool)
    live = np.ones(n_frames, dtype=bool)
    diag_rows = np.arange(4)
    # The curvature term of the Newton steps and its age in steps: finite
    # differences cost four model evaluations, so a frame reuses its term for
    # a few steps (near the minimum it hardly changes).
    curv_a = np.zeros((4, 4, n_frames))
    curv_age = np.full(n_frames, _CURVATURE_REFRESH)

    def finish(sel, code):
        """Write the frames ``sel`` (a mask over the active set) out."""
        out = idx[sel]
        state[out] = x_a[sel]
        cost[out] = c_a[sel]
        residuals[out] = aug_a[:, 4, sel].T.reshape(-1, n_nodes, 3)
        iterations[out] = it_a[sel]
        status[out] = code
        info_out[:, :, out] = info[:, :, sel]
        live[sel] = False

    while True:
        info, grad = _normal_equations(x_a, aug_a, prior_mean, prior_inv_sigma)
        # A non-finite state gives a non-finite cost (every frame here has a
        # measurement or a prior).
        bad = live & ~np.isfinite(c_a)
        if np.any(bad):
            finish(bad, _NONFINITE)
        if np.any(small_a & live):
            # The last accepted step was below tolerance.
            finish(small_a & live, _CONVERGED)
        if np.any(live & (it_a >= max_iterations)):
            finish(live & (it_a >= max_iterations), _MAX_ITER)
        n_live = int(np.count_nonzero(live))
        if n_live == 0:
            break
        if n_live < min_live:
            # Too few frames left for numpy to pay: hand them on (stage 2).
            finish(live.copy(), _MAX_ITER)
            break
        if n_live < 0.75 * live.size:
            # Compact the active set when enough frames are done.
            keep = live
            idx = idx[keep]
            if per_frame_poses:
                p_a = p_a[keep]
            z_a, w_a, x_a, c_a, aug_a = z_a[keep], w_a[keep], x_a[keep], c_a[keep], aug_a[..., keep]
            lam_a, nu_a, it_a = lam_a[keep], nu_a[keep], it_a[keep]
            curv_a, curv_age = curv_a[:, :, keep], curv_age[keep]
            info, grad = info[:, :, keep], grad[:, keep]
            live = np.ones(idx.size, dtype=bool)

        model = info
        slow = np.flatnonzero(live & (it_a >= params.newton_after))
        if slow.size:
            need = slow[curv_age[slow] >= _CURVATURE_REFRESH]
            if need.size:
                pp = p_a[need] if per_frame_poses else p_a
                curv_a[:, :, need] = _residual_curvature(x_a[need], pp, z_a[need], w_a[need],
                                                         inv_sigma, aug_a[..., need])
                curv_age[need] = 0
            curv_age[slow] += 1
            newton = info[:, :, slow] + curv_a[:, :, slow]
            # Newton only where its model is convex; elsewhere Gauss-Newton.
            use = chol_soa(newton)[1]
            model = info.copy()
            model[:, :, slow[use]] = newton[:, :, use]
        diag = model[diag_rows, diag_rows]
        # Marquardt damping on the diagonal, floored so that an unobservable
        # direction (zero diagonal) is still damped.
        floor = 1e-15 * np.maximum(np.abs(diag).max(axis=0), 1e-300)
        damped = model.copy()
        damping = lam_a * np.maximum(diag, floor)
        damped[diag_rows, diag_rows] += damping
        lo, ok = chol_soa(damped)
        step_t = solve_soa(lo, grad)
        step_t *= -1.0
        # The reduction of the cost that the local quadratic model predicts.
        decrement = -np.einsum("if,if->f", grad, step_t)
        # s^T M s = decrement - lambda s^T D s, since (M + lambda D) s = -g.
        predicted = 0.5 * (decrement + np.einsum("if,if->f", damping, step_t * step_t))
        # At a minimum the best possible decrease (the Newton decrement, when
        # the damping is light) is below the rounding of the cost itself.
        flat = live & ok & (lam_a <= 1e-2) & (decrement <= 1e-16 * np.maximum(c_a, 1.0))
        if np.any(flat):
            finish(flat, _CONVERGED)
            if not np.any(live):
                break

        step = step_t.T
        x_new = x_a + step
        aug_n, c_n = _evaluate(x_new, p_a, z_a, w_a, inv_sigma, prior_mean, prior_inv_sigma)
        it_a += live
        accept = live & ok & (c_n <= c_a)  # False for a NaN cost
        small_a = accept & np.all(np.abs(step_t) <= params.step_tolerance * (1.0 + np.abs(x_a.T)), axis=0)
        # Nielsen's damping update from the gain ratio actual / predicted.
        with np.errstate(divide="ignore", invalid="ignore"):
            gain = (c_a - c_n) / predicted
        gain = np.where(np.isfinite(gain), gain, 0.0)
        shrink = np.maximum(1.0 / 3.0, 1.0 - (2.0 * gain - 1.0) ** 3)
        lam_a = np.where(accept, np.maximum(lam_a * shrink, 1e-12), np.minimum(lam_a * nu_a, 1e12))
        nu_a = np.where(accept, 2.0, nu_a * 2.0)
        rejected = ~accept
        if np.any(rejected):
            np.copyto(x_new, x_a, where=rejected[:, None])
            np.copyto(c_n, c_a, where=rejected)
            np.copyto(aug_n, aug_a, where=rejected)
        x_a, c_a, aug_a = x_new, c_n, aug_n
        # A frame whose damping has grown without bound cannot move: it sits
        # at a minimum to rounding (typical when the cost is flat).
        small_a |= live & (lam_a >= 1e12)
    return state, cost, residuals, info_out, iterations, status
