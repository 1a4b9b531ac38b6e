"""Bayesian one-shot fusion of one frame (paper Sec. III-B, docs/CONVENTIONS.md, "One-shot fusion").

Every node that sees the target contributes a range, spatial-frequency and
Doppler measurement; with the Gaussian prior of paper eq. (16) the MAP state
minimizes the negative log posterior (paper eq. 18)

.. math::

    L(\\theta) = \\tfrac12 \\sum_i \\| (h(\\theta; S_i) \\ominus z_i) / \\sigma \\|^2
               + \\tfrac12 \\| (\\theta - m) / s \\|^2

(``prior=None`` drops the second term: maximum likelihood). The graph is one
``Vector4`` state with one measurement factor holding every observed node's
three measurements (:func:`factors.gtsam_factors.frame_measurement_factor`,
equivalent to one ``node_measurement_factor`` per node but half the Python
calls) and a ``PriorFactorVector``; GTSAM's Levenberg-Marquardt solves it from the
initial values of docs/CONVENTIONS.md and ``gtsam.Marginals`` gives the Laplace
covariance. The paper's grid posterior covariance is an option
(:mod:`mmsnap_graph.fusion.grid`).

A frame that cannot be solved (an indeterminate system, no convergence, a GTSAM
exception) gives ``FusionResult.success = False`` with a message; only invalid
input raises.

The problem itself (validation, initial values, the degeneracy indicator) is
GTSAM-free and lives in :mod:`mmsnap_graph.fusion.problem`; this module builds
the graph, solves it and assesses the solution. ``fuse_frame`` is the steps
validate (:func:`_check_options`, :func:`~.problem.validate_frame`),
initialise (:func:`_start`), build (:func:`_build`), solve (:func:`_solve`) and
assess (:func:`~.assess.assess_fit`).

Cost: ``benchmarks/bench_oneshot.py`` prints the per-frame median (two nodes,
configuration B) against ``scipy.optimize.least_squares`` with the same model.
Most of it is GTSAM calling the Python error function (~12 calls per frame);
for thousands of frames at once see :mod:`mmsnap_graph.fusion.solvers.vectorized`.

Two properties of the problem a user meets (tests/fusion/solvers/test_gtsam_graph.py):

- Mirror ambiguity: ranges are symmetric about the line through two nodes, so
  only the spatial frequencies (sigma pi/4) tell the target from its
  reflection across that line. With two nodes and the paper's noise about
  one frame in a few hundred has its MAP (the global optimum) at the mirror
  point; more nodes off that line remove it.
- Degenerate geometry: with the target near the line through two radars the
  cross-line velocity is unobservable from Doppler; the cost is a curved
  valley (Doppler measures roughly cross-line offset times cross-line
  velocity), LM needs ~20 iterations instead of ~4, ML velocity errors
  explode and ``FusionResult.degeneracy`` flags it.
"""

from __future__ import annotations

import math
from functools import lru_cache
from typing import Literal, Sequence

import gtsam
import numpy as np
from numpy.typing import ArrayLike, NDArray

from factors.gtsam_factors import frame_measurement_factor, measurement_noise, node_measurement_factor

from ...errors import MmsnapError, ValidationError
from ...data.noise import GaussianPrior, MeasurementNoise
from ...data.results import DEGENERACY_THRESHOLD, FusionResult, Status
from ...data.solution import FusionSolution
from ..grid import grid_posterior
from .assess import NEWTON_DECREMENT_TOLERANCE, assess_fit, residuals_and_degeneracy
from .gtsam_poses import pose_aware_covariance
from ..options import DEFAULT_OPTIONS, FusionOptions, RobustOptions, check_options, robust_options
from ..problem import (
    check_initial_state,
    check_node_noise,
    check_pose_covariances,
    check_prior,
    checked_initial_state,
    initial_state,
    initial_states,
    validate_frame,
    velocity_degeneracy,
)
from ..frame_problem import initial_states
from ..robust import node_d2, residual_gate_threshold, residual_test_fails
from .settings import LM_SETTINGS, LevenbergMarquardtSettings

__all__ = [
    "STATE_KEY",
    "NEWTON_DECREMENT_TOLERANCE",
    "build_frame_graph",
    "fuse_frame",
]

# Re-exported for callers of the old layout (the homes are data.noise,
# data.results and fusion.problem).
_COMPAT = (DEGENERACY_THRESHOLD, MeasurementNoise, GaussianPrior, FusionResult,
           initial_state, initial_states, validate_frame, velocity_degeneracy)

#: Key of the target state in the graphs built here.
STATE_KEY = 0



# ---------------------------------------------------------------------------
# Build


@lru_cache(maxsize=64)
def _noise_model(sigmas: tuple[float, float, float], n_nodes: int) -> gtsam.noiseModel.Base:
    return gtsam.noiseModel.Diagonal.Sigmas(np.tile(np.array(sigmas), n_nodes))


@lru_cache(maxsize=64)
def _node_noise_model(sigmas: tuple[float, ...]) -> gtsam.noiseModel.Base:
    # Per-node noise: the observed nodes' sigmas, node after node.
    return gtsam.noiseModel.Diagonal.Sigmas(np.array(sigmas))


def _sigmas(noise: MeasurementNoise) -> tuple[float, float, float]:
    return (noise.range_m, noise.omega_rad, noise.doppler_mps)


@lru_cache(maxsize=64)
def _prior_factor(mean: tuple[float, ...], sigmas: tuple[float, ...], key: int) -> gtsam.PriorFactorVector:
    # Immutable once built: one factor per prior is shared by every graph.
    return gtsam.PriorFactorVector(key, np.array(mean), gtsam.noiseModel.Diagonal.Sigmas(np.array(sigmas)))


#: Settings GTSAM's Python wrapper does not expose, at GTSAM's values.
_GTSAM_FIXED = {"min_model_fidelity": 1e-3, "min_diagonal": 1e-6, "max_diagonal": 1e32}


@lru_cache(maxsize=16)
def lm_params(settings: LevenbergMarquardtSettings = LM_SETTINGS) -> gtsam.LevenbergMarquardtParams:
    """GTSAM's ``LevenbergMarquardtParams`` mirroring ``settings`` (the rules
    the hand-written solvers follow step for step). GTSAM's Python wrapper
    cannot set the smallest model fidelity nor the clamp of the diagonal:
    settings that differ from GTSAM's fixed values there are refused."""
    for name, fixed in _GTSAM_FIXED.items():
        if getattr(settings, name) != fixed:
            raise ValidationError(f"the gtsam solver needs {name}={fixed!r} (GTSAM's value, "
                                  f"not settable from Python), got {getattr(settings, name)!r}")
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(settings.relative_tolerance)
    params.setAbsoluteErrorTol(settings.absolute_tolerance)
    params.setMaxIterations(int(settings.max_iterations))
    params.setlambdaInitial(settings.lambda_initial)
    params.setlambdaFactor(settings.lambda_factor)
    params.setlambdaLowerBound(settings.lambda_min)
    params.setlambdaUpperBound(settings.lambda_max)
    # Near-degenerate geometry (configuration C) makes the cost a curved,
    # banana-shaped valley in (x, vx): Doppler measures roughly x * vx there.
    # Marquardt's diagonal scaling and Nielsen's lambda update take ~19 LM
    # iterations on average there instead of ~84 with GTSAM's defaults (and
    # change nothing in benign geometry: ~4).
    params.setDiagonalDamping(True)
    params.setUseFixedLambdaFactor(False)
    return params


def build_frame_graph(
    node_poses: ArrayLike,
    measurements: ArrayLike,
    *,
    observed: ArrayLike | None = None,
    noise: MeasurementNoise | Sequence[MeasurementNoise] = MeasurementNoise(),
    prior: GaussianPrior | None = GaussianPrior(),
    initial_state: ArrayLike | None = None,
    key: int = STATE_KEY,
) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
    """The one-frame factor graph and its initial values, for users to extend.

    One :func:`~factors.gtsam_factors.frame_measurement_factor` with the
    range, spatial frequency and Doppler of every observed node (error of
    dimension ``3 n_observed``, node after node) and, unless ``prior`` is
    None, a ``PriorFactorVector``, all on the ``Vector4`` state at ``key``.
    Add factors (another target's, a motion model) before optimizing.
    ``initial_state`` (4,) defaults to :func:`~.problem.initial_state`.
    Inputs are validated as in :func:`fuse_frame` (``noise``: one
    :class:`MeasurementNoise` or one per node).
    """
    check_prior(prior)
    poses, z, obs = validate_frame(node_poses, measurements, observed)
    noise = check_node_noise(noise, poses.shape[0])
    if initial_state is None and obs is not None and not obs.any() and prior is None:
        raise ValidationError("observed has no True entry and there is no prior")
    x0 = _start(poses, z, obs, prior, noise, initial_state)
    return _build(poses, z, obs, noise, prior, x0, key)


@lru_cache(maxsize=16)
def _robust_model(sigmas: tuple[float, float, float], kernel: tuple[str, float]) -> gtsam.noiseModel.Base:
    return measurement_noise(np.array(sigmas), kernel[0], kernel[1])


def _build(poses, z, obs, noise, prior, x0, key, kernel=None):
    """The graph and values of one validated frame starting at ``x0``
    (``noise``: a tuple of N :class:`MeasurementNoise`, one per node);
    ``kernel`` ``(name, k)``: one robust factor per node (GTSAM's kernel acts
    on a factor's whole whitened error, so each node gets its own)."""
    graph = gtsam.NonlinearFactorGraph()
    if obs is not None:
        poses, z = poses[obs], z[obs]
        noise = [m for m, o in zip(noise, obs.tolist()) if o]
    n_obs = poses.shape[0]
    if n_obs and kernel is not None:
        for pose, zi, m in zip(poses, z, noise):
            graph.add(node_measurement_factor(key, pose, zi, _robust_model(_sigmas(m), kernel)))
    elif n_obs:
        if noise.count(noise[0]) == n_obs:  # one noise for every node (the common case)
            model = _noise_model(_sigmas(noise[0]), n_obs)
        else:
            model = _node_noise_model(tuple(v for m in noise for v in _sigmas(m)))
        graph.add(frame_measurement_factor(key, poses, z, model))
    if prior is not None:
        graph.add(_prior_factor(tuple(prior.mean.tolist()), tuple(prior.sigmas.tolist()), key))
    values = gtsam.Values()
    values.insert(key, np.asarray(x0, dtype=float))
    return graph, values


# ---------------------------------------------------------------------------
# Validate and initialise


def _start(poses, z, obs, prior, noise, initial_state) -> NDArray:
    """The starting state: the given one (checked) or the initial values."""
    if initial_state is None:
        return checked_initial_state(poses, z, obs, prior, noise)
    return check_initial_state(initial_state, poses, obs)


# ---------------------------------------------------------------------------
# Solve


class _Failure(Exception):
    """A frame that cannot be solved: status, message and what is known."""

    def __init__(self, status, message, state=None, iterations=0, cost=math.nan):
        super().__init__(message)
        self.status, self.message = status, message
        self.state, self.iterations, self.cost = state, iterations, cost


def _solve(graph, values, lm):
    """Levenberg-Marquardt and Marginals: ``(state, covariance, iterations,
    cost)``; raises :class:`_Failure` when the frame cannot be solved."""
    max_iterations = lm.max_iterations
    try:
        optimizer = gtsam.LevenbergMarquardtOptimizer(graph, values, lm_params(lm))
        solution = optimizer.optimize()
    except Exception as exc:  # GTSAM (or a callback) raised: flag the frame
        raise _Failure(Status.NON_FINITE, f"Levenberg-Marquardt failed: {type(exc).__name__}: {exc}")
    iterations = int(optimizer.iterations())
    state = solution.atVector(STATE_KEY)
    cost = float(optimizer.error())
    if not (math.isfinite(cost) and np.isfinite(state).all()):
        raise _Failure(Status.NON_FINITE, "Levenberg-Marquardt diverged to a non-finite state",
                       state, iterations, cost)
    if iterations >= max_iterations:
        raise _Failure(
            Status.MAX_ITERATIONS,
            f"Levenberg-Marquardt did not converge within max_iterations={max_iterations}",
            state, iterations, cost,
        )
    try:
        cov = gtsam.Marginals(graph, solution).marginalCovariance(STATE_KEY)
    except Exception as exc:
        raise _Failure(
            Status.SINGULAR,
            "indeterminate linear system at the solution, no covariance "
            f"({type(exc).__name__}: {exc})",
            state, iterations, cost,
        )
    return state, 0.5 * (cov + cov.T), iterations, cost


def _grid(state, cov, poses, z, obs, noise, prior, points, half_width, messages):
    """The grid covariance of a solved frame (its message joins ``messages``)."""
    grid = grid_posterior(state, poses, z, observed=obs, noise=noise[0], prior=prior,
                          scale_covariance=cov, points_per_axis=points,
                          half_width_sigmas=half_width)
    if grid.message:
        messages.append(grid.message)
    return grid.covariance


# ---------------------------------------------------------------------------
# The public call


def fuse_frame(
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
) -> FusionResult:
    """Bayesian (or ML) one-shot fusion of one frame (paper eqs. 15-18).

    Parameters
    ----------
    node_poses : (N, 3) float
        Node poses ``(x_m, y_m, phi_rad)`` in the global frame (N >= 1).
    measurements : (N, 3) float
        ``(range_m, omega_rad, doppler_mps)`` per node. Missing data: without
        ``observed``, an all-NaN row means the node did not observe the
        target (:func:`~.problem.validate_frame`).
    observed : (N,) bool, optional
        Which nodes saw the target (default: the rows that are not all NaN);
        unobserved rows may hold anything.
    noise : MeasurementNoise or sequence of N MeasurementNoise
        Measurement sigmas (default: the paper's), or one per node in the
        order of ``node_poses`` (docs/CONVENTIONS.md, "Per-node noise").
    prior : GaussianPrior or None
        The Gaussian prior (MAP, default the paper's); None for ML.
    initial_state : (4,) float, optional
        Starting state (default: :func:`~.problem.initial_state`).
    pose_covariances : (N, 3, 3) float, optional
        Calibration-aware fusion (docs/CONVENTIONS.md): each pose's covariance
        in the Pose2 body tangent, all NaN (or zero) for an exact pose. The
        estimate is unchanged; the covariance is ``gtsam.Marginals`` of the
        graph with the uncertain poses as variables under their priors
        (:mod:`~mmsnap_graph.fusion.solvers.gtsam_poses`). Needs
        ``options.covariance="laplace"``.
    robust : RobustOptions, "gate", "huber", "cauchy" or None
        Robust fusion (:mod:`mmsnap_graph.fusion.robust`; default None; a
        name is :class:`~mmsnap_graph.fusion.options.RobustOptions` with its
        defaults). ``"gate"``: a frame whose whitened residuals fail the
        chi-square test is refitted without each node in turn; the one
        passing refit is kept (``rejected``; the covariance of the
        measurements kept), else ``Status.RESIDUAL_TEST_FAILED``.
        ``"huber"`` / ``"cauchy"``: GTSAM's kernels per node, started from
        the plain fit.
    options : FusionOptions
        ``options.lm``: Levenberg-Marquardt's settings (``max_iterations``:
        reaching it is a failure). ``options.covariance``: ``"laplace"``
        (``gtsam.Marginals`` only), ``"grid"`` / ``"both"`` (also the paper's
        numerical posterior covariance on a 4D grid laid out along the
        Laplace one, ``result.grid_covariance``; layout
        ``options.grid_points_per_axis``, ``options.grid_half_width_sigmas``,
        see :func:`mmsnap_graph.fusion.grid.grid_posterior`).

    Returns
    -------
    FusionResult
        ``success=False`` with a status and a message when the system is
        indeterminate, LM does not converge or GTSAM raises (never raised);
        ``success=True``: a finite state and a positive-definite covariance.

    Raises
    ------
    ValidationError, GeometryError
        Invalid input (see :func:`~.problem.validate_frame`), or an initial
        position (given, or from the detections) on an observed node.
    """
    check_prior(prior)
    options = check_options(options)
    covariance, lm = options.covariance, options.lm
    robust = robust_options(robust)
    kernel = None if robust is None else robust.kernel_pair
    poses, z, obs, noise, pose_cov = _validate(node_poses, measurements, observed, noise,
                                               pose_covariances, covariance)
    n_observed = poses.shape[0] if obs is None else int(obs.sum())
    frame = dict(n_nodes=poses.shape[0], n_observed=n_observed, prior=prior, covariance=covariance)
    if n_observed == 0 and prior is None:
        return _failed(_Failure(Status.NO_INFORMATION, "no node observed the target and there "
                                "is no prior: the state is indeterminate"), None, **frame)
    x0 = _start(poses, z, obs, prior, noise, initial_state)
    try:
        fit = _fit(poses, z, obs, noise, prior, x0, lm)
        fit, rejected = _robust_step(fit, poses, z, obs, noise, prior, lm, robust)
    except _Failure as failure:
        return _failed(failure, x0, **frame)
    kept = obs if rejected is None or robust.kernel != "gate" else _kept(obs, rejected)
    if pose_cov is not None and fit.status == Status.OK:
        fit.cov = _pose_aware(fit, poses, z, kept, noise, prior, kernel, pose_cov)
    grid_cov = None
    if covariance != "laplace":
        grid_cov = (_grid(fit.state, fit.cov, poses, z, kept, noise, prior,
                          options.grid_points_per_axis, options.grid_half_width_sigmas,
                          fit.messages)
                    if fit.status == Status.OK else np.full((4, 4), np.nan))
    return _result(fit, grid_cov, n_observed, prior, rejected)


def _validate(node_poses, measurements, observed, noise, pose_covariances, covariance):
    """``(poses, z, obs, noise per node, pose covariances or None)`` of one frame."""
    poses, z, obs = validate_frame(node_poses, measurements, observed)
    noise = check_node_noise(noise, poses.shape[0])
    pose_cov = _check_pose_options(pose_covariances, poses.shape[0], noise, covariance)
    return poses, z, obs, noise, pose_cov


def _check_pose_options(pose_covariances, n_nodes, noise, covariance):
    """The validated pose covariances (None: every pose exact); per-node noise
    and pose covariances need the Laplace covariance only (the grid has one
    noise and fixed poses)."""
    pose_cov = check_pose_covariances(pose_covariances, n_nodes)
    if covariance != "laplace":
        if pose_cov is not None:
            raise ValidationError(
                f"pose_covariances needs covariance='laplace', got covariance={covariance!r} "
                "(the grid posterior takes the poses as exact)")
        if noise.count(noise[0]) != len(noise):
            raise ValidationError(
                f"per-node noise needs covariance='laplace', got covariance={covariance!r} "
                "(the grid posterior takes one noise for every node)")
    return pose_cov


def _pose_aware(fit, poses, z, obs, noise, prior, kernel, pose_cov):
    """The calibration-aware covariance of a solved frame; a failure keeps the
    frame but flags it singular (no covariance)."""
    try:
        return pose_aware_covariance(fit.state, poses, z, obs, noise, prior, pose_cov, kernel)
    except Exception as exc:  # GTSAM: an indeterminate joint system
        fit.status = Status.SINGULAR
        fit.messages = [f"calibration-aware covariance failed ({type(exc).__name__}: {exc})"]
        return np.full((4, 4), np.nan)


def _result(fit, grid_cov, n_observed, prior, rejected) -> FusionResult:
    """The FusionResult of an assessed fit."""
    for arr in (fit.state, fit.cov, fit.whitened, fit.x0):
        arr.setflags(write=False)  # handed over without a copy
    return FusionResult(
        state=fit.state,
        covariance=fit.cov,
        success=fit.status == Status.OK,
        status=fit.status,
        message="; ".join(fit.messages),
        iterations=fit.iterations,
        final_cost=fit.cost,
        whitened_residuals=fit.whitened,
        degeneracy=fit.degeneracy,
        grid_covariance=grid_cov,
        initial_state=fit.x0,
        n_observed=n_observed,
        used_prior=prior is not None,
        rejected=rejected,
    )


def _robust_step(fit, poses, z, obs, noise, prior, lm, robust):
    """The gate or the kernel fit after the plain fit: ``(fit, rejected or None)``;
    raises :class:`_Failure` when the kernel fit fails."""
    if fit.status != Status.OK or robust is None:
        return fit, None
    if robust.kernel == "gate":
        return _gate(fit, poses, z, obs, noise, prior, lm, robust.gate_probability)
    # The kernel fit starts from the plain one (a non-convex kernel from the
    # detections' average can stall in a wrong basin).
    x0 = fit.x0
    fit = _fit(poses, z, obs, noise, prior, fit.state.copy(), lm, robust.kernel_pair)
    fit.x0 = x0
    return fit, node_d2(fit.whitened) > robust.threshold


class _Fit:
    """One solved and assessed frame."""

    __slots__ = ("state", "cov", "iterations", "cost", "status", "messages", "whitened",
                 "degeneracy", "x0")

    def __init__(self, **kwargs):
        for name, value in kwargs.items():
            setattr(self, name, value)


def _fit(poses, z, obs, noise, prior, x0, lm, kernel=None) -> _Fit:
    """Build, solve and assess one frame from ``x0``; raises :class:`_Failure`."""
    graph, values = _build(poses, z, obs, noise, prior, x0, STATE_KEY, kernel)
    state, cov, iterations, cost = _solve(graph, values, lm)
    status, messages, whitened, degeneracy = assess_fit(state, cov, poses, z, obs, noise, prior, kernel)
    return _Fit(state=state, cov=cov, iterations=iterations, cost=cost, status=status,
                messages=messages, whitened=whitened, degeneracy=degeneracy, x0=x0)


def _kept(obs, rejected):
    """The observed flags without the rejected nodes."""
    return (np.ones(rejected.shape, dtype=bool) if obs is None else obs) & ~rejected


def _gate(fit, poses, z, obs, noise, prior, lm, probability):
    """``robust="gate"`` on a solved frame: ``(fit, rejected (N,) or None)``
    (as :func:`mmsnap_graph.fusion.solvers.vectorized.fuse_batch`'s gate): the passing
    leave-one-node-out refit when exactly one passes."""
    if not residual_test_fails(fit.whitened, probability):
        return fit, None
    d2 = node_d2(fit.whitened)
    threshold = residual_gate_threshold(probability)
    n_nodes = poses.shape[0]
    seen = np.ones(n_nodes, dtype=bool) if obs is None else obs
    best, best_node, n_pass = None, -1, 0
    if seen.sum() >= 3:
        for n in np.flatnonzero(seen):
            kept = seen.copy()
            kept[n] = False
            try:
                sub = _fit(poses, z, kept, noise, prior,
                           checked_initial_state(poses, z, kept, prior, noise), lm)
            except (_Failure, MmsnapError):
                continue
            if sub.status != Status.OK or residual_test_fails(sub.whitened, probability):
                continue
            n_pass += 1
            if best is None or sub.cost < best.cost:
                best, best_node = sub, int(n)
    if n_pass != 1:
        fit.status = Status.RESIDUAL_TEST_FAILED
        fit.cov = np.full((4, 4), np.nan)
        fit.messages = [f"{Status.RESIDUAL_TEST_FAILED.message} ("
                        + ("ambiguous: several nodes' removal passes" if n_pass else
                           f"largest squared whitened residual {d2.max():.3g}") + ")"]
        return fit, None
    best.whitened = residuals_and_degeneracy(best.state, poses, z, obs, noise, prior)[0]
    best.messages = best.messages + [f"node {best_node} rejected by the residual gate "
                                     f"(squared whitened residual {d2[best_node]:.3g} "
                                     f"> {threshold:.3g} before the refit)"]
    rejected = np.zeros(n_nodes, dtype=bool)
    rejected[best_node] = True
    return best, rejected


def _failed(failure: _Failure, x0, *, n_nodes, n_observed, prior, covariance) -> FusionResult:
    """The result of a frame that could not be solved."""
    nan44 = np.full((4, 4), np.nan)
    return FusionResult(
        state=np.full(4, np.nan) if failure.state is None else failure.state,
        covariance=nan44,
        success=False,
        status=failure.status,
        message=failure.message,
        iterations=failure.iterations,
        final_cost=float(failure.cost),
        whitened_residuals=np.full((n_nodes, 3), np.nan),
        degeneracy=math.inf,
        grid_covariance=None if covariance == "laplace" else nan44,
        initial_state=np.full(4, np.nan) if x0 is None else x0,
        n_observed=n_observed,
        used_prior=prior is not None,
    )


# ---------------------------------------------------------------------------
# The solve contract


def solve_frames(problem, options: FusionOptions = DEFAULT_OPTIONS):
    """Every frame of a :class:`~mmsnap_graph.fusion.frame_problem.FrameProblem`
    solved by GTSAM (one graph per frame, Levenberg-Marquardt, ``Marginals``;
    with uncertain poses the joint graph's marginal): a
    :class:`~mmsnap_graph.data.solution.FusionSolution` with the Laplace
    covariance (:func:`mmsnap_graph.fusion.solve.solve`)."""
    n_frames, n_nodes = problem.n_frames, problem.n_nodes
    state = np.full((n_frames, 4), np.nan)
    cov = np.full((n_frames, 4, 4), np.nan)
    status = np.zeros(n_frames, dtype=np.int8)
    iterations = np.zeros(n_frames, dtype=np.int64)
    cost = np.full(n_frames, np.nan)
    whitened = np.full((n_frames, n_nodes, 3), np.nan)
    degeneracy = np.full(n_frames, np.inf)
    x0 = initial_states(problem)
    noise, prior, kernel, lm = problem.noise, problem.prior, problem.kernel, options.lm
    for f in range(n_frames):
        poses = problem.poses if problem.poses.ndim == 2 else problem.poses[f]
        z, seen = problem.measurements[f], problem.observed[f]
        obs = None if seen.all() else seen
        if prior is None and not seen.any():
            status[f] = Status.NO_INFORMATION
            continue
        if not np.isfinite(x0[f]).all():  # the average detection on a node
            status[f] = Status.NON_FINITE
            continue
        try:
            fit = _fit(poses, z, obs, noise, prior, x0[f], lm, kernel)
        except _Failure as failure:
            status[f], iterations[f], cost[f] = failure.status, failure.iterations, failure.cost
            if failure.state is not None:
                state[f] = failure.state
            continue
        state[f], status[f], iterations[f], cost[f] = fit.state, fit.status, fit.iterations, fit.cost
        whitened[f], degeneracy[f] = fit.whitened, fit.degeneracy
        if fit.status != Status.OK:
            continue
        cov[f] = fit.cov
        if problem.pose_covariances is not None:
            try:
                cov[f] = pose_aware_covariance(fit.state, poses, z, obs, noise, prior,
                                               problem.pose_covariances, kernel)
            except Exception:  # GTSAM: an indeterminate joint system
                status[f], cov[f] = Status.SINGULAR, np.nan
    return FusionSolution(state=state, covariance=cov, status=status, iterations=iterations,
                          final_cost=cost, initial_state=x0, whitened_residuals=whitened,
                          degeneracy=degeneracy)
