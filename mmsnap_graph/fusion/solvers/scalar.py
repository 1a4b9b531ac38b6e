"""One-shot fusion one frame at a time, in plain Python floats:
``solver="scalar"`` of :func:`mmsnap_graph.fusion.solve.solve` (:func:`solve_frames`),
the solver of the stream (:class:`mmsnap_graph.fusion.stream.frame_stream.FrameStream`,
docs/STREAMING.md).

The same problem as GTSAM's (:mod:`mmsnap_graph.fusion.solvers.gtsam_graph`):
the cost ``0.5 * sum of squared whitened residuals`` of every observed node's
range, spatial frequency (wrapped) and Doppler, each node with its own
sigmas (with a robust kernel, the kernel's loss and each node weighted by
its IRLS weight, as GTSAM's robust noise model), plus the Gaussian prior
(MAP; none for ML), from the same initial state
(:func:`~mmsnap_graph.fusion.frame_problem.initial_states`). It is
minimized by Levenberg-Marquardt (Marquardt's diagonal damping and Nielsen's
update, as the GTSAM settings) and the covariance is the inverse of the
Gauss-Newton information ``J^T W J + Lambda_prior`` at the solution (what
``gtsam.Marginals`` returns for that graph). With uncertain node poses the
covariance is the marginal of the state in the joint graph of
:mod:`mmsnap_graph.fusion.solvers.gtsam_poses` (each uncertain pose a variable
under its prior, linearized at the estimate and the calibrated poses),
computed here as a Schur complement: the same number as GTSAM's.

Why floats: a frame has four unknowns and ``3 N`` residuals; numpy's
per-call overhead on arrays of that size costs more than the arithmetic, and
a GTSAM graph costs a Python callback per evaluation plus the graph's own
fixed cost. Here one Levenberg-Marquardt iteration of four nodes is a few
microseconds of arithmetic: the model is
:func:`factors.models.measurement_model_scalar` (the GTSAM factor's), the
information and gradient are accumulated entry by entry (a node's Jacobian
is sparse: range and spatial frequency do not depend on the velocity) and
the 4x4 Cholesky factorization is unrolled.

The iteration is GTSAM's Levenberg-Marquardt step for step (the initial
lambda, its update from the model fidelity, Marquardt's diagonal clamped as
GTSAM clamps it, the relative and absolute error tolerances of 1e-14), so
that both reach the same local minimum (two nodes can have a mirror
minimum) and stop alike; they differ by rounding (GTSAM solves the normal
equations by its own elimination). ``tests/fusion/test_solve.py`` checks
the two against each other through :func:`~mmsnap_graph.fusion.solve.solve`
(MAP, ML, missed nodes, per-node noise, uncertain poses, degenerate
geometry, robust fits): statuses equal, states to :data:`STATE_TOLERANCE`
and covariances to :data:`COVARIANCE_TOLERANCE`, both relative to the
standard deviations.

Status codes as GTSAM's: ``NON_FINITE`` for an initial position on a node,
a non-finite solution or a Newton decrement above
:data:`~mmsnap_graph.fusion.solvers.assess.NEWTON_DECREMENT_TOLERANCE`;
``MAX_ITERATIONS``; ``SINGULAR`` when the information is not positive
definite (an ML frame seen by one node); ``NO_INFORMATION`` for no node and
no prior.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np
from numpy.typing import NDArray

from factors.models import measurement_model_scalar, wrap_angle_scalar

from ...data.noise import GaussianPrior, MeasurementNoise
from ...data.results import Status
from ...data.solution import FusionSolution
from ...errors import ValidationError
from ..._floats4 import cholesky_4x4, cholesky_inverse_4x4, cholesky_solve_4x4, forward_4x4
from ..degeneracy import condition_2x2
from ..frame_problem import initial_state_floats
from ..frame_problem import initial_states as start_states
from .assess import NEWTON_DECREMENT_TOLERANCE
from .settings import LM_SETTINGS, LevenbergMarquardtSettings

__all__ = ["STATE_TOLERANCE", "COVARIANCE_TOLERANCE", "solve_frames"]

#: Largest difference between this solver's state and GTSAM's, in
#: units of each component's standard deviation (measured: 3e-7 at most,
#: typically 1e-10).
STATE_TOLERANCE = 1e-6
#: Largest difference between the covariances, relative to
#: ``sigma_i sigma_j`` (measured: 2.5e-6 at most).
COVARIANCE_TOLERANCE = 1e-5

_EPSILON = 2.220446049250313e-16
# oneshot_assess.positive_definite's smallest eigenvalue ratio of a covariance.
_MIN_EIGENVALUE_RATIO = 1e-13
# Relative Cholesky pivot below which the information counts as singular
# (as mmsnap_graph._linalg's batched Cholesky).
_PIVOT_RTOL = 1e-12
_OK, _MAX_ITER, _SINGULAR, _NON_FINITE, _NO_INFORMATION = (
    int(Status.OK), int(Status.MAX_ITERATIONS), int(Status.SINGULAR), int(Status.NON_FINITE),
    int(Status.NO_INFORMATION))


def _positive_definite(c: list[float]) -> bool:
    """:func:`~mmsnap_graph.fusion.solvers.assess.positive_definite` in
    floats: every squared Cholesky pivot of the covariance ``c`` (16 floats,
    row-major) above ``_MIN_EIGENVALUE_RATIO`` times its largest diagonal
    entry, all finite."""
    floor = _MIN_EIGENVALUE_RATIO * max(c[0], c[5], c[10], c[15])
    if not (c[0] > 0.0 and c[0] > floor and math.isfinite(floor)):
        return False
    l00 = math.sqrt(c[0])
    l10, l20, l30 = c[4] / l00, c[8] / l00, c[12] / l00
    d = c[5] - l10 * l10
    if not d > floor:
        return False
    l11 = math.sqrt(d)
    l21, l31 = (c[9] - l20 * l10) / l11, (c[13] - l30 * l10) / l11
    d = c[10] - l20 * l20 - l21 * l21
    if not d > floor:
        return False
    l32 = (c[14] - l30 * l20 - l31 * l21) / math.sqrt(d)
    d = c[15] - l30 * l30 - l31 * l31 - l32 * l32
    return d > floor and math.isfinite(d)


_NAN16 = [math.nan] * 16


class _FrameSolver:
    """The one-shot solver of one network: node poses, per-node sigmas, prior
    and pose covariances, precomputed once; :meth:`solve` fuses one group.

    node_poses : (N, 3) float, validated; noises : N
    :class:`MeasurementNoise` (node order); prior : GaussianPrior or None;
    pose_covariances : (N, 3, 3) with NaN for an exact pose, or None
    (validated by :func:`~mmsnap_graph.fusion.problem.check_pose_covariances`);
    lm : the Levenberg-Marquardt settings, as GTSAM's; kernel : ``(name, k)``
    or None.
    """

    def __init__(self, node_poses: NDArray, noises: Sequence[MeasurementNoise],
                 prior: GaussianPrior | None, pose_covariances: NDArray | None = None,
                 lm: LevenbergMarquardtSettings = LM_SETTINGS,
                 kernel: tuple[str, float] | None = None) -> None:
        poses = np.asarray(node_poses, dtype=float)
        self.kernel = kernel
        self.poses = poses
        self.noises = tuple(noises)
        self.prior = prior
        self.lm = lm
        self._nodes = [(px, py, math.cos(phi), math.sin(phi)) for px, py, phi in poses.tolist()]
        self._inv_sigma = [(1.0 / m.range_m, 1.0 / m.omega_rad, 1.0 / m.doppler_mps)
                           for m in self.noises]
        if prior is None:
            self._prior = None
        else:
            inv2 = (1.0 / prior.sigmas**2).tolist()
            self._prior = (prior.mean.tolist(), inv2)
        # Each uncertain pose's information (its covariance's inverse), None for an exact one.
        self._pose_info = None
        if pose_covariances is not None:
            self._pose_info = [None if np.isnan(c).all() else np.linalg.inv(0.5 * (c + c.T))
                               for c in np.asarray(pose_covariances, dtype=float)]

    # ------------------------------------------------------------------
    def _normal(self, x, rows):
        """``(cost, H (16 floats, row-major), g (4), (a11, a12, a22),
        residuals)`` at ``x``: the Gauss-Newton information and gradient of
        the cost (each node weighted by the kernel's IRLS weight), the
        lines-of-sight sums of the degeneracy and each observed node's plain
        whitened residuals ``(n, e_r, e_w, e_v)``. ``rows``: (node, z)
        pairs of the observed nodes. Raises ZeroDivisionError for a state on
        a node."""
        x0, x1, x2, x3 = x
        cost = 0.0
        h00 = h01 = h11 = h02 = h03 = h12 = h13 = h22 = h23 = h33 = 0.0
        g0 = g1 = g2 = g3 = 0.0
        a11 = a12 = a22 = 0.0
        nodes, inv_sigma, kernel = self._nodes, self._inv_sigma, self.kernel
        residuals = []
        for n, (zr, zw, zv) in rows:
            px, py, c, s = nodes[n]
            r, w, v, j = measurement_model_scalar(x0, x1, x2, x3, px, py, c, s)
            sr, sw, sv = inv_sigma[n]
            er = (r - zr) * sr
            ew = wrap_angle_scalar(w - zw) * sw
            ev = (v - zv) * sv
            residuals.append((n, er, ew, ev))
            ux, uy = j[0], j[1]
            a11 += ux * ux
            a12 += ux * uy
            a22 += uy * uy
            s2 = er * er + ew * ew + ev * ev
            if kernel is None:
                cost += s2
            else:  # GTSAM's robust model: the loss, and rows scaled by sqrt(weight)
                wt, loss = _kernel(kernel, s2)
                cost += 2.0 * loss
                q = math.sqrt(wt)
                sr, sw, sv = sr * q, sw * q, sv * q
                er, ew, ev = er * q, ew * q, ev * q
            rx, ry = ux * sr, uy * sr                      # whitened range row (rx, ry, 0, 0)
            wx, wy = j[4] * sw, j[5] * sw                  # spatial frequency row (wx, wy, 0, 0)
            dx, dy, dvx, dvy = j[8] * sv, j[9] * sv, ux * sv, uy * sv   # Doppler row
            h00 += rx * rx + wx * wx + dx * dx
            h01 += rx * ry + wx * wy + dx * dy
            h11 += ry * ry + wy * wy + dy * dy
            h02 += dx * dvx
            h03 += dx * dvy
            h12 += dy * dvx
            h13 += dy * dvy
            h22 += dvx * dvx
            h23 += dvx * dvy
            h33 += dvy * dvy
            g0 += rx * er + wx * ew + dx * ev
            g1 += ry * er + wy * ew + dy * ev
            g2 += dvx * ev
            g3 += dvy * ev
        cost *= 0.5
        if self._prior is not None:
            (m0, m1, m2, m3), (p0, p1, p2, p3) = self._prior
            d0, d1, d2, d3 = x0 - m0, x1 - m1, x2 - m2, x3 - m3
            cost += 0.5 * (p0 * d0 * d0 + p1 * d1 * d1 + p2 * d2 * d2 + p3 * d3 * d3)
            h00 += p0
            h11 += p1
            h22 += p2
            h33 += p3
            g0 += p0 * d0
            g1 += p1 * d1
            g2 += p2 * d2
            g3 += p3 * d3
        info = [h00, h01, h02, h03, h01, h11, h12, h13, h02, h12, h22, h23, h03, h13, h23, h33]
        return cost, info, (g0, g1, g2, g3), (a11, a12, a22), residuals

    def _lm(self, x, rows):
        """Levenberg-Marquardt from ``x``, step for step as GTSAM's
        ``LevenbergMarquardtOptimizer`` with the GTSAM settings
        (so that both reach the same local minimum and stop alike): ``(x,
        cost, H, g, lines, residuals, iterations, converged)``."""
        lm = self.lm
        cost, info, grad, lines, res = self._normal(x, rows)
        lam, factor = lm.lambda_initial, lm.lambda_factor
        lo_diag, hi_diag = lm.min_diagonal, lm.max_diagonal
        it = 0
        while it < lm.max_iterations:
            it += 1
            previous = cost
            # Marquardt's damping: lambda times the clamped diagonal of H.
            diag = (min(max(info[0], lo_diag), hi_diag), min(max(info[5], lo_diag), hi_diag),
                    min(max(info[10], lo_diag), hi_diag), min(max(info[15], lo_diag), hi_diag))
            while True:
                step = self._try(x, cost, info, grad, lam, diag, rows)
                if step is not None and step[0]:
                    _, fidelity, new_x, new = step
                    lam = max(lm.lambda_min, lam * lm.damping_update(fidelity))
                    factor = 2.0
                    x = new_x
                    cost, info, grad, lines, res = new
                    break
                if step is not None and step[1] is None:
                    break  # the cost change is below rounding: stop searching lambda
                lam *= factor
                factor *= 2.0
                if lam >= lm.lambda_max:
                    break  # giving up: cannot decrease the cost with the largest lambda
            decrease = previous - cost
            if (cost <= 0.0 or decrease <= lm.relative_tolerance * previous
                    or decrease <= lm.absolute_tolerance):
                return x, cost, info, grad, lines, res, it, True
        return x, cost, info, grad, lines, res, it, False

    def _try(self, x, cost, info, grad, lam, diag, rows):
        """One damped step (GTSAM's ``tryLambda``): None when the damped system
        is not positive definite or the linearized cost grows; else
        ``(successful, fidelity, x_new, normal equations at x_new)``, with
        fidelity None when the cost change is below rounding."""
        (h00, h01, h02, h03, _, h11, h12, h13, _, _, h22, h23, _, _, _, h33) = info
        damped = [h00 + lam * diag[0], h01, h02, h03, h01, h11 + lam * diag[1], h12, h13,
                  h02, h12, h22 + lam * diag[2], h23, h03, h13, h23, h33 + lam * diag[3]]
        lo = cholesky_4x4(damped, _PIVOT_RTOL)
        if lo is None:
            return None
        s0, s1, s2, s3 = cholesky_solve_4x4(lo, grad)
        d0, d1, d2, d3 = -s0, -s1, -s2, -s3
        # The undamped model's decrease: -(g.d + d^T H d / 2) (H symmetric).
        hd0 = h00 * d0 + h01 * d1 + h02 * d2 + h03 * d3
        hd1 = h01 * d0 + h11 * d1 + h12 * d2 + h13 * d3
        hd2 = h02 * d0 + h12 * d1 + h22 * d2 + h23 * d3
        hd3 = h03 * d0 + h13 * d1 + h23 * d2 + h33 * d3
        linearized = -(grad[0] * d0 + grad[1] * d1 + grad[2] * d2 + grad[3] * d3
                       + 0.5 * (d0 * hd0 + d1 * hd1 + d2 * hd2 + d3 * hd3))
        if not linearized >= 0.0:
            return None
        x_new = [x[0] + d0, x[1] + d1, x[2] + d2, x[3] + d3]
        try:
            new = self._normal(x_new, rows)
        except ZeroDivisionError:
            new = (math.inf, None, None, None, None)
        change = cost - new[0]
        fidelity = 0.0
        if linearized > _EPSILON * cost:
            fidelity = change / linearized
            successful = fidelity > self.lm.min_model_fidelity
        else:
            successful = True  # the linearized change is zero to rounding
        if not successful and abs(change) < self.lm.relative_tolerance * cost:
            return False, None, x_new, new
        return successful, fidelity, x_new, new

    # ------------------------------------------------------------------
    def solve(self, z: list, observed: list, x0: list[float]) -> tuple:
        """Fuse one group from ``x0`` (4 floats, finite): ``z`` (N rows of 3
        floats) each node's measurement (rows of the unobserved nodes
        ignored), ``observed`` (N bools; at least one True, or a prior).
        Returns ``(state, covariance (16 floats, row-major) or None, status, degeneracy,
        iterations, cost, residuals)`` (``residuals``: ``(n, e_r, e_w,
        e_v)`` of the observed nodes at ``state``, empty when unknown)."""
        rows = [(n, z[n]) for n in range(len(observed)) if observed[n]]
        try:
            x, cost, info, grad, lines, res, it, converged = self._lm(x0, rows)
        except ZeroDivisionError:  # the initial state on a node
            return [math.nan] * 4, None, _NON_FINITE, math.inf, 0, math.nan, ()
        status, cov, degeneracy = self._assess(x, cost, info, grad, lines, converged, rows)
        return x, cov, status, degeneracy, it, cost, res

    def _assess(self, x, cost, info, grad, lines, converged, rows) -> tuple:
        """``(status, covariance or None, degeneracy)`` of a solution (as GTSAM's)."""
        if not (math.isfinite(cost) and all(map(math.isfinite, x))):
            return _NON_FINITE, None, math.inf
        if not converged:
            return _MAX_ITER, None, math.inf
        lo = cholesky_4x4(info, _PIVOT_RTOL)
        if lo is None:  # indeterminate system (gtsam.Marginals raises)
            return _SINGULAR, None, math.inf
        cov = cholesky_inverse_4x4(lo)
        degeneracy = condition_2x2(*lines)
        if not _positive_definite(cov):
            return _SINGULAR, None, degeneracy
        # The squared Newton decrement g^T H^-1 g = |L^-1 g|^2.
        y = forward_4x4(lo, grad)
        if not y[0] * y[0] + y[1] * y[1] + y[2] * y[2] + y[3] * y[3] <= NEWTON_DECREMENT_TOLERANCE:
            return _NON_FINITE, None, degeneracy
        if self._pose_info is not None:
            cov = self._pose_aware(x, info, rows)
            if cov is None:
                return _SINGULAR, None, degeneracy
        return _OK, cov, degeneracy

    def _pose_aware(self, x, info, rows) -> list[float] | None:
        """The state's marginal covariance (16 floats, row-major) in the
        joint graph with the uncertain poses (Schur complement of the pose
        blocks); None when singular."""
        h = np.array(info).reshape(4, 4)
        for n, (zr, zw, zv) in rows:
            pose_info = self._pose_info[n]
            if pose_info is None:
                continue
            px, py, c, s = self._nodes[n]
            _, _, _, j_state, j_pose = measurement_model_scalar(*x, px, py, c, s, pose_jacobian=True)
            inv_sigma = np.array(self._inv_sigma[n])[:, None]
            if self.kernel is not None:  # the node's IRLS weight at x
                r, w, v, _ = measurement_model_scalar(*x, px, py, c, s)
                e = np.array([r - zr, wrap_angle_scalar(w - zw), v - zv]) * inv_sigma[:, 0]
                inv_sigma = inv_sigma * math.sqrt(_kernel(self.kernel, float(e @ e))[0])
            jx = np.array(j_state).reshape(3, 4) * inv_sigma
            jp = np.array(j_pose).reshape(3, 3) * inv_sigma
            h_xp = jx.T @ jp
            h_pp = jp.T @ jp + pose_info
            try:
                h = h - h_xp @ np.linalg.solve(h_pp, h_xp.T)
            except np.linalg.LinAlgError:
                return None
        lo = cholesky_4x4((0.5 * (h + h.T)).ravel().tolist(), _PIVOT_RTOL)
        if lo is None:
            return None
        return cholesky_inverse_4x4(lo)


def _kernel(kernel: tuple[str, float], s2: float) -> tuple[float, float]:
    """``(IRLS weight, loss)`` of GTSAM's Huber or Cauchy kernel at squared
    whitened norm ``s2`` (as :func:`~mmsnap_graph.fusion.robust.kernel_weight_and_loss`)."""
    name, k = kernel
    if name == "huber":
        s = math.sqrt(s2)
        return (1.0, 0.5 * s2) if s <= k else (k / s, k * s - 0.5 * k * k)
    q = s2 / (k * k)
    return 1.0 / (1.0 + q), 0.5 * k * k * math.log1p(q)


def _solver_of(problem, lm: LevenbergMarquardtSettings) -> _FrameSolver:
    """The :class:`_FrameSolver` of ``problem``'s network (made once per network)."""
    # Keyed by the settings' identity (hashing the frozen settings costs more
    # than the lookup); the settings object is kept with its solver.
    held, solver = problem.cached(("scalar", id(lm), problem.kernel), lambda: (lm, _FrameSolver(
        problem.poses, problem.noise, problem.prior, problem.pose_covariances, lm, problem.kernel)))
    if held is not lm:  # an id reused by other settings
        solver = _FrameSolver(problem.poses, problem.noise, problem.prior,
                              problem.pose_covariances, lm, problem.kernel)
    return solver


def solve_frames(problem, options):
    """Every frame of a :class:`~mmsnap_graph.fusion.frame_problem.FrameProblem`
    solved one at a time in plain floats: a
    :class:`~mmsnap_graph.data.solution.FusionSolution` with the Laplace
    covariance (:func:`mmsnap_graph.fusion.solve.solve`)."""
    if problem.poses.ndim == 3:
        raise ValidationError("the scalar solver takes one network for every frame "
                              "(poses (N, 3)); use solver='vectorized' or 'gtsam'")
    solver = _solver_of(problem, options.lm)
    n_nodes = problem.n_nodes
    z_all, obs_all = problem.measurements.tolist(), problem.observed.tolist()
    if problem.initial_state is None:
        # The floats of start_states(per_frame=True), from the lists held here.
        x0_all = initial_state_floats(problem, z_all, obs_all)
        x0 = np.array(x0_all, dtype=float).reshape(len(z_all), 4)
    else:
        x0 = start_states(problem, per_frame=True)
        x0_all = x0.tolist()
    no_prior = problem.prior is None
    # One flat list of floats per frame (state 4, covariance 16, cost,
    # degeneracy, whitened residuals 3 N), made one array at the end: numpy's
    # per-item writes and per-field arrays cost more than the floats.
    nan4, nan3n = [math.nan] * 4, [math.nan] * (3 * n_nodes)
    flat, status, iterations = [], [], []
    for z, obs, start in zip(z_all, obs_all, x0_all):
        if no_prior and not any(obs):
            x, c, st, dg, it, fc, res = nan4, None, _NO_INFORMATION, math.inf, 0, math.nan, ()
        elif not all(map(math.isfinite, start)):  # the average detection on a node
            x, c, st, dg, it, fc, res = nan4, None, _NON_FINITE, math.inf, 0, math.nan, ()
        else:
            x, c, st, dg, it, fc, res = solver.solve(z, obs, start)
        w = list(nan3n)
        for n, er, ew, ev in res:
            w[3 * n], w[3 * n + 1], w[3 * n + 2] = er, ew, ev
        flat += x
        flat += _NAN16 if c is None else c
        flat.append(fc)
        flat.append(dg)
        flat += w
        status.append(st)
        iterations.append(it)
    n_frames = len(status)
    table = np.array(flat, dtype=float).reshape(n_frames, 22 + 3 * n_nodes)
    state = table[:, :4]
    cov = table[:, 4:20].reshape(n_frames, 4, 4)
    cost, degeneracy = table[:, 20], table[:, 21]
    whitened = table[:, 22:].reshape(n_frames, n_nodes, 3)
    status = np.array(status, dtype=np.int8)
    iterations = np.array(iterations, dtype=np.int64)
    return FusionSolution.of_solver(state=state, covariance=cov, status=status,
                                    iterations=iterations, final_cost=cost, initial_state=x0,
                                    whitened_residuals=whitened, degeneracy=degeneracy)
