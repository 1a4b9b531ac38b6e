"""The one solve contract of one-shot fusion (docs/CONVENTIONS.md, "One-shot fusion"):

- :func:`solve`: a :class:`~mmsnap_graph.fusion.frame_problem.FrameProblem`
  and :class:`~mmsnap_graph.fusion.options.FusionOptions` in, a
  :class:`~mmsnap_graph.data.solution.FusionSolution` out, whichever solver
  ``options.solver`` names: ``"gtsam"`` (the reference: one factor graph of
  custom factors per frame, Levenberg-Marquardt and ``gtsam.Marginals``,
  :mod:`.solvers.gtsam_graph`), ``"vectorized"`` (numpy over the frames,
  :mod:`.solvers.vectorized`) or ``"scalar"`` (plain floats, one frame at a
  time, :mod:`.solvers.scalar`); the tests hold the other two equal to GTSAM
  through this function (tests/fusion/test_solve.py);
- :func:`robust_solve`: the robust fit as a wrapper around :func:`solve`, for
  any solver (:mod:`.robust`, docs/ROBUST.md): the residual gate (a frame
  whose residuals fail the chi-square test is solved again without each of
  its nodes in turn; the one passing refit is kept, the node reported
  ``rejected``, else ``Status.RESIDUAL_TEST_FAILED``), or GTSAM's Huber and
  Cauchy kernels (the kernel fit started from the plain one).

A frame that cannot be solved gets a status, never an exception; only an
invalid problem raises (when it is made).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Literal

import numpy as np

from ..data.results import Status
from ..data.solution import FusionSolution
from ..errors import MmsnapError, ValidationError
from .frame_problem import FrameProblem, whitened_residuals
from .options import DEFAULT_OPTIONS, FusionOptions, RobustOptions, check_options, robust_options
from .robust import node_d2, residual_test_fails
from .solvers import scalar, vectorized

__all__ = ["solve", "robust_solve", "with_grid_covariance", "check_grid_model"]


def check_grid_model(problem: FrameProblem, options: FusionOptions) -> None:
    """ValidationError when ``options.covariance="grid"`` meets a problem the
    grid posterior cannot model (per-node noise, uncertain poses)."""
    if options.covariance == "grid" and (problem.pose_covariances is not None
                                         or not problem.one_noise):
        raise ValidationError(
            "covariance='grid' takes one noise for every node and exact poses (the grid "
            "posterior's model); per-node noise and pose_covariances need covariance='laplace'")


def _check(problem: object, options: object) -> tuple[FrameProblem, FusionOptions]:
    if not isinstance(problem, FrameProblem):
        raise ValidationError(f"problem must be a FrameProblem, got {type(problem).__name__}")
    options = check_options(options)
    check_grid_model(problem, options)
    return problem, options


def solve(problem: FrameProblem, options: FusionOptions = DEFAULT_OPTIONS) -> FusionSolution:
    """Solve every frame of ``problem`` with ``options.solver``.

    The MAP state (ML without a prior) of each frame, its Laplace covariance
    (with uncertain node poses, theirs included: GTSAM and the scalar solver
    marginalize the poses in the joint graph, the vectorized solver adds them
    by linear propagation), the status, iterations, cost, whitened residuals
    and velocity degeneracy; with ``options.covariance="grid"`` also the
    paper's grid posterior covariance of the frames that succeeded
    (``grid_covariance``; a frame whose grid fails gets
    ``Status.GRID_FAILED``). ``problem.kernel`` makes it the robust kernel's
    fit (:func:`robust_solve` sets it).
    """
    problem, options = _check(problem, options)
    solution = _solve_laplace(problem, options)
    if options.covariance == "grid":
        solution = with_grid_covariance(solution, problem, options)
    return solution


def _gtsam_solve_frames(problem: FrameProblem, options: FusionOptions) -> FusionSolution:
    """The GTSAM solver, imported when first asked for (GTSAM only then); the
    import resolved once, not on every frame of a per-frame caller."""
    from .solvers.gtsam_graph import solve_frames

    _SOLVERS["gtsam"] = solve_frames
    return solve_frames(problem, options)


#: Each solver's ``solve_frames`` by the name ``FusionOptions.solver`` gives.
_SOLVERS = {"gtsam": _gtsam_solve_frames, "vectorized": vectorized.solve_frames,
            "scalar": scalar.solve_frames}


def _solve_laplace(problem: FrameProblem, options: FusionOptions) -> FusionSolution:
    return _SOLVERS[options.solver](problem, options)


def with_grid_covariance(solution: FusionSolution, problem: FrameProblem,
                         options: FusionOptions) -> FusionSolution:
    """``solution`` with the grid posterior covariance of each frame that
    succeeded, over the nodes it kept (``options.grid_points_per_axis``,
    ``options.grid_half_width_sigmas``); a failing grid: ``Status.GRID_FAILED``."""
    from .grid import grid_posterior  # deferred: scipy only for the grid

    grid = np.full(solution.covariance.shape, np.nan)
    status = np.array(solution.status)
    kept = problem.observed & ~solution.rejected if problem.kernel is None else problem.observed
    for f in np.flatnonzero(solution.success):
        try:
            post = grid_posterior(solution.state[f], problem.poses if problem.poses.ndim == 2
                                  else problem.poses[f], problem.measurements[f],
                                  observed=kept[f], noise=problem.noise[0], prior=problem.prior,
                                  scale_covariance=solution.covariance[f],
                                  points_per_axis=options.grid_points_per_axis,
                                  half_width_sigmas=options.grid_half_width_sigmas)
        except MmsnapError:
            status[f] = Status.GRID_FAILED
            continue
        grid[f] = post.covariance
    return replace(solution, status=status, grid_covariance=grid)


# ---------------------------------------------------------------------------
# The robust fit


def robust_solve(problem: FrameProblem, options: FusionOptions = DEFAULT_OPTIONS,
                 robust: RobustOptions | Literal["gate", "huber", "cauchy"] | None = None,
                 ) -> FusionSolution:
    """:func:`solve` with the robust fit ``robust`` (None: :func:`solve` itself),
    for any solver.

    ``"gate"`` (:class:`~mmsnap_graph.fusion.options.RobustOptions`): after the
    plain fit each frame's whitened residuals are tested (each node's against
    ``chi2.ppf(p, 3)``, their sum against ``chi2.ppf(p, 3 n - 4)``); a failing
    frame with at least three nodes is solved again without each node in turn,
    and the passing refit is kept when exactly one passes (its
    ``whitened_residuals`` are those of every observed node at the refit's
    state, the left-out node ``rejected``), else the frame is
    ``Status.RESIDUAL_TEST_FAILED`` (no covariance). ``"huber"`` /
    ``"cauchy"``: the kernel's fit (``problem.with_kernel``) started from the
    plain one where it succeeded; ``rejected`` the nodes whose residual fails
    the gate (down-weighted, not removed).
    """
    problem, options = _check(problem, options)
    robust = robust_options(robust)
    laplace = replace(options, covariance="laplace") if options.covariance != "laplace" else options
    least_squares = problem if problem.kernel is None else problem.with_kernel(None)
    plain = _solve_laplace(least_squares, laplace)
    if robust is None:
        solution = plain
    elif robust.kernel == "gate":
        solution = _gate(plain, least_squares, laplace, robust.gate_probability)
    else:
        solution = _kernel_fit(plain, problem, laplace, robust)
        problem = problem.with_kernel(robust.kernel_pair)
    if options.covariance == "grid":
        solution = with_grid_covariance(solution, problem, options)
    return solution


def _kernel_fit(plain: FusionSolution, problem: FrameProblem, options: FusionOptions,
                robust: RobustOptions) -> FusionSolution:
    """The kernel fit started from the plain one (a non-convex kernel from the
    detections' average can stall in a wrong basin)."""
    x0 = plain.initial_state
    ok = plain.success & np.isfinite(plain.state).all(axis=1)
    start = np.where(ok[:, None], plain.state, x0)
    startable = np.isfinite(start).all(axis=1)
    fitted = problem.with_kernel(robust.kernel_pair)
    if not startable.all():  # frames that never started keep the initial values
        rows = np.flatnonzero(startable)
        sub = _solve_laplace(fitted[rows].with_initial_state(start[rows]), options)
        solution = _merge(plain, rows, sub)
    else:
        solution = _solve_laplace(fitted.with_initial_state(start), options)
    rejected = (node_d2(solution.whitened_residuals) > robust.threshold) & problem.observed \
        & solution.success[:, None]
    return replace(solution, initial_state=x0, rejected=rejected)


#: The per-frame fields a refit replaces.
_FIELDS = ("state", "covariance", "status", "iterations", "final_cost", "initial_state",
           "whitened_residuals", "degeneracy", "rejected")


def _merge(base: FusionSolution, rows, sub: FusionSolution) -> FusionSolution:
    """``base`` with frames ``rows`` taken from ``sub`` (one per row)."""
    out = {name: np.array(getattr(base, name)) for name in _FIELDS}
    for name in _FIELDS:
        out[name][rows] = getattr(sub, name)
    return replace(base, **out)


def _gate(plain: FusionSolution, problem: FrameProblem, options: FusionOptions,
          probability: float) -> FusionSolution:
    """The residual gate on a solved problem (:func:`robust_solve`)."""
    obs = problem.observed
    failing = np.flatnonzero(plain.success & residual_test_fails(plain.whitened_residuals,
                                                                 probability))
    if failing.size == 0:
        return plain
    best = np.full(failing.size, -1)
    best_cost = np.full(failing.size, np.inf)
    n_pass = np.zeros(failing.size, dtype=np.int64)
    refits = {}
    enough = obs[failing].sum(axis=1) >= 3
    for n in range(problem.n_nodes):
        sel = obs[failing, n] & enough
        if not sel.any():
            continue
        rows = failing[sel]
        mask = obs[rows].copy()
        mask[:, n] = False
        sub = _solve_laplace(problem[rows].with_observed(mask), options)
        ok = sub.success & ~residual_test_fails(sub.whitened_residuals, probability)
        n_pass[sel] += ok
        better = ok & (sub.final_cost < best_cost[sel])
        best[np.flatnonzero(sel)[better]] = n
        best_cost[np.flatnonzero(sel)[better]] = sub.final_cost[better]
        refits[n] = (rows, sub)
    best[n_pass != 1] = -1  # none, or ambiguous: which node is the outlier?
    out = {name: np.array(getattr(plain, name)) for name in _FIELDS}
    for n, (rows, sub) in refits.items():
        take = best[np.searchsorted(failing, rows)] == n
        for name in _FIELDS:
            out[name][rows[take]] = getattr(sub, name)[take]
        out["rejected"][rows[take], n] = True
    fixed = failing[best >= 0]
    if fixed.size:
        out["whitened_residuals"][fixed] = whitened_residuals(problem[fixed], out["state"][fixed])
    lost = failing[best < 0]
    out["status"][lost] = Status.RESIDUAL_TEST_FAILED
    out["covariance"][lost] = np.nan
    return replace(plain, **out)

