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
covariance.

This is the reference solver of :func:`mmsnap_graph.fusion.solve.solve`
(``solver="gtsam"``): :func:`solve_frames` builds (:func:`_build`), solves
(:func:`_solve`) and assesses (:func:`~.assess.assess_fit`) each frame of a
:class:`~mmsnap_graph.fusion.frame_problem.FrameProblem` (validated when it
was made). A frame that cannot be solved (an indeterminate system, no
convergence, a GTSAM exception) gets a status, never an exception.

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
  explode and ``FusionSolution.degeneracy`` flags it.
"""

from __future__ import annotations

import math
from functools import lru_cache
import gtsam
import numpy as np

from factors.gtsam_factors import frame_measurement_factor, measurement_noise, node_measurement_factor

from ...data.noise import MeasurementNoise
from ...data.results import Status
from ...data.solution import FusionSolution
from ...errors import GeometryError, ValidationError
from ..frame_problem import FrameProblem, initial_states
from ..options import DEFAULT_OPTIONS, FusionOptions
from .assess import NEWTON_DECREMENT_TOLERANCE, assess_fit
from .gtsam_poses import build_pose_aware_graph, pose_aware_covariance
from .settings import LM_SETTINGS, LevenbergMarquardtSettings

__all__ = [
    "STATE_KEY",
    "NEWTON_DECREMENT_TOLERANCE",
    "lm_params",
    "build_frame_graph",
    "solve_frames",
]

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


def build_frame_graph(problem: FrameProblem, frame: int = 0, *, key: int = STATE_KEY
                      ) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
    """The factor graph of one frame of ``problem`` and its initial values,
    for users to extend.

    One :func:`~factors.gtsam_factors.frame_measurement_factor` with the
    range, spatial frequency and Doppler of every observed node (error of
    dimension ``3 n_observed``, node after node; with ``problem.kernel`` one
    robust factor per node) and, unless the prior is None, a
    ``PriorFactorVector``, all on the ``Vector4`` state at ``key``, started
    at :func:`~mmsnap_graph.fusion.frame_problem.initial_states`. Add factors
    (another target's, a motion model) before optimizing. GeometryError when
    that start is undefined (the detections average onto a node).
    """
    x0 = initial_states(problem[frame], per_frame=True)[0]
    if not np.isfinite(x0).all():
        raise GeometryError(f"frame {frame} has no initial state ({x0.tolist()}): no node "
                            "observes it without a prior, or its detections average onto a node")
    seen = problem.observed[frame]
    poses = problem.poses if problem.poses.ndim == 2 else problem.poses[frame]
    return _build(poses, problem.measurements[frame], None if seen.all() else seen,
                  problem.noise, problem.prior, x0, key, problem.kernel)


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


# ---------------------------------------------------------------------------
# The solve contract


def _fit(poses, z, obs, noise, prior, x0, lm, kernel=None):
    """Build, solve and assess one frame from ``x0``: ``(state, covariance,
    iterations, cost, status, whitened residuals, degeneracy)``; raises
    :class:`_Failure` when it cannot be solved."""
    graph, values = _build(poses, z, obs, noise, prior, x0, STATE_KEY, kernel)
    state, cov, iterations, cost = _solve(graph, values, lm)
    status, _, whitened, degeneracy = assess_fit(state, cov, poses, z, obs, noise, prior, kernel)
    return state, cov, iterations, cost, status, whitened, degeneracy


def solve_frames(problem: FrameProblem, options: FusionOptions = DEFAULT_OPTIONS) -> FusionSolution:
    """Every frame of a :class:`~mmsnap_graph.fusion.frame_problem.FrameProblem`
    solved by GTSAM (one graph per frame, Levenberg-Marquardt, ``Marginals``;
    with uncertain poses the joint graph's marginal): a
    :class:`~mmsnap_graph.data.solution.FusionSolution` with the Laplace
    covariance (:func:`mmsnap_graph.fusion.solve.solve`)."""
    n_frames, n_nodes = problem.n_frames, problem.n_nodes
    x0 = initial_states(problem, per_frame=True)
    noise, prior, kernel, lm = problem.noise, problem.prior, problem.kernel, options.lm
    one_network = problem.poses.ndim == 2
    if n_frames == 1:  # the per-frame caller: plain floats beat numpy's reductions
        seen = problem.observed[0].tolist()
        seen_all, seen_any = [all(seen)], [any(seen)]
        startable = [all(map(math.isfinite, x0[0].tolist()))]
    else:
        seen_all = problem.observed.all(axis=1).tolist()
        seen_any = problem.observed.any(axis=1).tolist()
        startable = np.isfinite(x0).all(axis=1).tolist()
    # Each frame's results in lists, made arrays once (per-frame writes into
    # preallocated arrays cost more than the one frame of the stream's solves).
    nan4, nan44, nan_w = _NAN4, _NAN44, np.full((n_nodes, 3), np.nan)
    state, cov, status, iterations, cost, whitened, degeneracy = [], [], [], [], [], [], []
    for f in range(n_frames):
        poses = problem.poses if one_network else problem.poses[f]
        z = problem.measurements[f]
        obs = None if seen_all[f] else problem.observed[f]
        if prior is None and not seen_any[f]:
            row = nan4, nan44, Status.NO_INFORMATION, 0, math.nan, nan_w, math.inf
        elif not startable[f]:  # the average detection on a node
            row = nan4, nan44, Status.NON_FINITE, 0, math.nan, nan_w, math.inf
        else:
            try:
                x, c, it, fc, st, w, dg = _fit(poses, z, obs, noise, prior, x0[f], lm, kernel)
            except _Failure as failure:
                x = nan4 if failure.state is None else failure.state
                row = x, nan44, failure.status, failure.iterations, failure.cost, nan_w, math.inf
            else:
                if st != Status.OK:
                    c = nan44
                elif problem.pose_covariances is not None:
                    try:
                        c = pose_aware_covariance(*build_pose_aware_graph(
                            x, poses, z, obs, noise, prior, problem.pose_covariances, kernel))
                    except Exception:  # GTSAM: an indeterminate joint system
                        st, c = Status.SINGULAR, nan44
                row = x, c, st, it, fc, w, dg
        state.append(row[0])
        cov.append(row[1])
        status.append(row[2])
        iterations.append(row[3])
        cost.append(row[4])
        whitened.append(row[5])
        degeneracy.append(row[6])
    return FusionSolution.of_solver(
        state=np.array(state, dtype=float).reshape(n_frames, 4),
        covariance=np.array(cov, dtype=float).reshape(n_frames, 4, 4),
        status=np.array(status, dtype=np.int8), iterations=np.array(iterations, dtype=np.int64),
        final_cost=np.array(cost, dtype=float), initial_state=x0,
        whitened_residuals=np.array(whitened, dtype=float).reshape(n_frames, n_nodes, 3),
        degeneracy=np.array(degeneracy, dtype=float))


#: The state and covariance of a frame that has none.
_NAN4 = np.full(4, np.nan)
_NAN44 = np.full((4, 4), np.nan)
_NAN4.setflags(write=False)
_NAN44.setflags(write=False)
