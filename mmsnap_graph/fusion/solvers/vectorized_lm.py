"""The vectorized Levenberg-Marquardt solver of :mod:`mmsnap_graph.fusion.solvers.vectorized`.

:func:`evaluate` (whitened Jacobian, residuals and cost of ``F`` frames, frames
last), :func:`normal_equations`, :func:`residual_curvature` (the second-order
term of the Newton steps) and :func:`levenberg_marquardt` (damped Gauss-Newton
over the frame axis with Nielsen's damping update and an active set). See the
module docstring of :mod:`mmsnap_graph.fusion.solvers.vectorized` for how it is fast.
Each node has its own sigmas (``SolverParams.inv_sigma`` (N, 3)).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from factors.models import measurement_model, wrap_angle

from ..._linalg import chol_soa, solve_soa
from ...data.results import Status
from ..robust import kernel_weight_and_loss
from .settings import LM_SETTINGS, LevenbergMarquardtSettings

__all__ = [
    "SolverParams",
    "evaluate",
    "normal_equations",
    "residual_curvature",
    "levenberg_marquardt",
]

# Status codes (the status arrays are int8).
_CONVERGED, _MAX_ITER, _NONFINITE = (
    int(Status.OK), int(Status.MAX_ITERATIONS), int(Status.NON_FINITE))

# Steps a frame reuses the finite-difference curvature of its Newton steps.
_CURVATURE_REFRESH = 3


def evaluate(state, poses, z, weight, inv_sigma, prior_mean, prior_inv_sigma, kernel=None):
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
        inv_n = inv_sigma[n] if inv_sigma.ndim == 2 else inv_sigma  # per-node (N, 3) or (3,)
        w = inv_n[:, None] * weight[:, n] if partial else inv_n[:, None]  # (3, F) or (3, 1)
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


def normal_equations(state, aug, prior_mean, prior_inv_sigma):
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


def residual_curvature(state, poses, z, weight, inv_sigma, aug, kernel=None):
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
        aug_k, _ = evaluate(shifted, poses, z, weight, inv_sigma, None, None, kernel)
        diff = aug_k[:, :4] - aug[:, :4]
        curv[k] = np.einsum("mf,mjf->jf", r, diff) / eps
    return 0.5 * (curv + curv.transpose(1, 0, 2))


@dataclass(frozen=True, slots=True)
class SolverParams:
    """Settings of :func:`levenberg_marquardt`: ``inv_sigma`` (N, 3) (each
    node's inverse sigmas; (3,) for one noise), the prior's mean and inverse
    sigmas (None: ML), the step tolerance, ``newton_after``, the robust
    kernel ``(name, k)`` or None and the damping rules ``lm`` (its
    ``lambda_initial``, ``lambda_factor``, ``lambda_min`` and ``lambda_max``;
    the convergence test is the step tolerance, not the cost's)."""

    inv_sigma: NDArray
    prior_mean: NDArray | None
    prior_inv_sigma: NDArray | None
    step_tolerance: float
    newton_after: int
    kernel: tuple | None = None
    lm: LevenbergMarquardtSettings = LM_SETTINGS


class _Frames:
    """The frames of one :func:`_lm` call: the output arrays (indexed by frame)
    and the active set (arrays with an ``_a`` suffix, indexed by ``idx``)."""

    def __init__(self, x0, poses, z, weight, params, it_start, damping=None):
        n_frames, n_nodes = z.shape[:2]
        self.n_nodes = n_nodes
        self.per_frame_poses = poses.ndim == 3
        self.state = np.empty((n_frames, 4))
        self.cost = np.empty(n_frames)
        self.residuals = np.empty((n_frames, n_nodes, 3))
        self.info_out = np.empty((4, 4, n_frames))
        self.iterations = np.empty(n_frames, dtype=np.int64)
        self.status = np.empty(n_frames, dtype=np.int8)
        self.lam_out = np.empty(n_frames)
        self.nu_out = np.empty(n_frames)
        self.idx = np.arange(n_frames)
        self.p_a, self.z_a, self.w_a, self.x_a = poses, z, weight, x0
        self.aug_a, self.c_a = evaluate(x0, poses, z, weight, params.inv_sigma,
                                         params.prior_mean, params.prior_inv_sigma, params.kernel)
        if damping is None:
            self.lam_a = np.full(n_frames, params.lm.lambda_initial)
            self.nu_a = np.full(n_frames, params.lm.lambda_factor)
        else:  # a frame continued from an earlier call keeps its damping
            self.lam_a, self.nu_a = (np.array(d, dtype=float) for d in damping)
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
        self.lam_out[out], self.nu_out[out] = self.lam_a[sel], self.nu_a[sel]
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
        return (self.state, self.cost, self.residuals, self.info_out, self.iterations, self.status,
                (self.lam_out, self.nu_out))


def levenberg_marquardt(x0, poses, z, weight, params, it_start, max_iterations, min_live=0,
                        damping=None):
    """Levenberg-Marquardt over the frames of ``x0 (F, 4)``.

    Returns ``state (F, 4)``, ``cost (F,)``, ``residuals (F, N, 3)``,
    ``info (4, 4, F)`` (undamped information at the returned state),
    ``iterations (F,)`` (counting from ``it_start``), ``status (F,)`` and
    ``damping`` ``(lambda (F,), factor (F,))``; frames still running after
    ``max_iterations`` have status ``_MAX_ITER``. ``damping`` continues
    frames from an earlier call where they stopped (default: the settings'
    ``lambda_initial`` and ``lambda_factor``), so that how the frames are
    split into calls does not change any frame's steps.
    """
    fr = _Frames(x0, poses, z, weight, params, it_start, damping)
    while True:
        fr.info, fr.grad = normal_equations(fr.x_a, fr.aug_a, params.prior_mean, params.prior_inv_sigma)
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
            fr.curv_a[:, :, need] = residual_curvature(fr.x_a[need], pp, fr.z_a[need], fr.w_a[need],
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
    aug_n, c_n = evaluate(x_new, fr.p_a, fr.z_a, fr.w_a, params.inv_sigma,
                           params.prior_mean, params.prior_inv_sigma, params.kernel)
    fr.it_a += live
    accept = live & ok & (c_n <= c_a)  # False for a NaN cost
    fr.small_a = accept & np.all(np.abs(step_t) <= params.step_tolerance * (1.0 + np.abs(x_a.T)), axis=0)
    # Nielsen's damping update from the gain ratio actual / predicted.
    with np.errstate(divide="ignore", invalid="ignore"):
        gain = (c_a - c_n) / predicted
    gain = np.where(np.isfinite(gain), gain, 0.0)
    shrink = np.maximum(1.0 / 3.0, 1.0 - (2.0 * gain - 1.0) ** 3)
    lm = params.lm
    fr.lam_a = np.where(accept, np.maximum(fr.lam_a * shrink, lm.lambda_min),
                        np.minimum(fr.lam_a * fr.nu_a, lm.lambda_max))
    fr.nu_a = np.where(accept, 2.0, fr.nu_a * 2.0)
    rejected = ~accept
    if np.any(rejected):
        np.copyto(x_new, x_a, where=rejected[:, None])
        np.copyto(c_n, c_a, where=rejected)
        np.copyto(aug_n, fr.aug_a, where=rejected)
    fr.x_a, fr.c_a, fr.aug_a = x_new, c_n, aug_n
    # A frame whose damping has grown without bound cannot move: it sits
    # at a minimum to rounding (typical when the cost is flat).
    fr.small_a |= live & (fr.lam_a >= lm.lambda_max)
