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

Cost (``benchmarks/bench_oneshot.py``, two nodes, configuration B): ~0.155 ms
per frame for validation, initial values, LM (median 4 iterations) and
``Marginals`` on a loaded 2-core machine, ~4.5x faster than
``scipy.optimize.least_squares`` with the same model. Most of it is GTSAM
calling the Python error function (~12 calls per frame); for thousands of
frames at once see :mod:`mmsnap_graph.fusion.batch`.

Two properties of the problem a user meets (tests/test_oneshot.py):

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
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Literal

import gtsam
import numpy as np
from numpy.typing import ArrayLike, NDArray

from factors.gtsam_factors import frame_measurement_factor
from factors.models import (
    MEASUREMENT_NAMES,
    detection_to_global,
    measurement_model_scalar,
    wrap_angle_scalar,
)

from ..errors import GeometryError, ValidationError
from .._validation import as_float_array, check_finite, frozen_vector
from ..data.noise import GaussianPrior, MeasurementNoise

__all__ = [
    "STATE_KEY",
    "DEGENERACY_THRESHOLD",
    "NEWTON_DECREMENT_TOLERANCE",
    "MeasurementNoise",
    "GaussianPrior",
    "FusionResult",
    "validate_frame",
    "initial_state",
    "initial_states",
    "build_frame_graph",
    "fuse_frame",
    "velocity_degeneracy",
]

#: An initial position closer than this to a node is "at the node": its line
#: of sight (and the model's Jacobian) is undefined to rounding.
_AT_NODE_M = 1e-9
#: Largest squared Newton decrement ``g^T S g`` (cost units) accepted at a
#: solution; converged frames show ~1e-15 (1e-12 in configuration C).
NEWTON_DECREMENT_TOLERANCE = 1e-8
#: Key of the target state in the graphs built here.
STATE_KEY = 0
#: ``FusionResult.degeneracy`` above this flags a degenerate geometry: for two
#: nodes, lines of sight within about 11.4 degrees of parallel (the condition
#: number of two unit vectors at angle ``a`` is ``cot^2(a / 2)``), where the
#: cross-line velocity from Doppler alone is ~7x worse than along the line.
#: Indicative values at the estimate: configuration B ~1.6, A ~6, C with the
#: target on the line through the radars ~175 (median; the estimate's own
#: cross-line error makes it finite).
DEGENERACY_THRESHOLD = 100.0


@dataclass(frozen=True, kw_only=True, slots=True)
class FusionResult:
    """The one-shot estimate of one frame.

    Attributes
    ----------
    state : (4,) float
        MAP (or ML) ``(x_m, y_m, vx_mps, vy_mps)`` in the global frame; the
        last iterate when ``success`` is False.
    covariance : (4, 4) float
        Laplace covariance from ``gtsam.Marginals`` (the inverse Gauss-Newton
        information at ``state``); NaN when it could not be computed.
    success : bool
        True when the optimizer converged and the covariance exists.
    message : str
        Why it failed, or notes (e.g. a degenerate geometry).
    iterations : int
        Levenberg-Marquardt iterations.
    final_cost : float
        GTSAM's graph error at ``state``: half the sum of squared whitened
        residuals, prior included (half of the paper's ``L``).
    whitened_residuals : (N, 3) float
        ``(h(state) - z) / sigma`` per node (spatial frequency wrapped), in
        measurement order; NaN rows for nodes that did not observe the target.
    degeneracy : float
        Condition number (>= 1) of the 2x2 velocity block of the measurement
        information at ``state``, ``sum_i u_i u_i^T / sigma_V^2`` over observed
        nodes (``u_i`` the line of sight; only Doppler informs velocity
        directly). 1 for orthogonal lines of sight, ``inf`` when they are
        parallel (a target on the line through two radars) or with a single
        node: then only the prior bounds the cross-line velocity. It ignores
        the prior on purpose, so it describes the geometry.
        See :data:`DEGENERACY_THRESHOLD`.
    grid_covariance : (4, 4) float or None
        The paper's numerical posterior covariance over a 4D grid around
        ``state`` (:func:`mmsnap_graph.fusion.grid.grid_posterior`), when
        ``covariance`` was ``"grid"`` or ``"both"``; None otherwise.
    initial_state : (4,) float
        Where the optimizer started.
    n_observed : int
        Number of nodes that observed the target.
    used_prior : bool
        True for MAP (Bayesian), False for ML.
    """

    state: NDArray
    covariance: NDArray
    success: bool
    message: str
    iterations: int
    final_cost: float
    whitened_residuals: NDArray
    degeneracy: float
    grid_covariance: NDArray | None = None
    initial_state: NDArray
    n_observed: int
    used_prior: bool

    def __post_init__(self) -> None:
        for name in ("state", "covariance", "whitened_residuals", "grid_covariance", "initial_state"):
            value = getattr(self, name)
            if value is None:
                continue
            # Read-only float arrays owning their data (what fuse_frame hands
            # over) are kept; anything else is copied and frozen.
            if not (
                type(value) is np.ndarray
                and value.dtype == np.float64
                and value.flags.owndata
                and not value.flags.writeable
            ):
                value = np.array(value, dtype=float)
                value.setflags(write=False)
                object.__setattr__(self, name, value)

    @property
    def degenerate(self) -> bool:
        """``degeneracy > DEGENERACY_THRESHOLD``."""
        return bool(self.degeneracy > DEGENERACY_THRESHOLD)

    @property
    def position_sigma_m(self) -> NDArray:
        """(2,) float: 1-sigma of ``(x, y)`` from the Laplace covariance."""
        return np.sqrt(np.diag(self.covariance)[:2])

    @property
    def velocity_sigma_mps(self) -> NDArray:
        """(2,) float: 1-sigma of ``(vx, vy)`` from the Laplace covariance."""
        return np.sqrt(np.diag(self.covariance)[2:])


# ---------------------------------------------------------------------------
# Validation


def _check_poses(node_poses: ArrayLike) -> NDArray:
    poses = as_float_array(node_poses, "node_poses")
    if poses.ndim != 2 or poses.shape[1] != 3:
        raise ValidationError(f"node_poses must have shape (N, 3), got {poses.shape}")
    if poses.shape[0] == 0:
        raise ValidationError("node_poses must hold at least one node, got shape (0, 3)")
    if not _all_finite(poses):
        check_finite(poses, "node_poses")
    return poses


def _all_finite(arr: NDArray) -> bool:
    # Plain floats beat numpy's temporaries for the few numbers of one frame.
    if arr.size <= 64:
        return all(map(math.isfinite, arr.ravel().tolist()))
    return bool(np.isfinite(arr).all())


def _check_observed(observed: ArrayLike | None, n_nodes: int) -> NDArray | None:
    if observed is None:
        return None
    obs = np.asarray(observed)
    if obs.dtype != bool:
        raise ValidationError(f"observed must be a boolean array, got dtype {obs.dtype}")
    if obs.shape != (n_nodes,):
        raise ValidationError(
            f"observed must have shape ({n_nodes},) (one flag per node), got {obs.shape}"
        )
    return None if obs.all() else obs


def _check_measurement_rows(z: NDArray, rows: NDArray) -> None:
    """Detailed errors for the observed measurement rows (slow path)."""
    for i in rows:
        for j, name in enumerate(MEASUREMENT_NAMES):
            value = float(z[i, j])
            if not math.isfinite(value):
                raise ValidationError(
                    f"measurements[{i}, {j}] ({name} of node {i}) must be finite, got {value!r}"
                )
        rng_m, omega = float(z[i, 0]), float(z[i, 1])
        if rng_m < 0.0:
            raise ValidationError(
                f"measurements[{i}, 0] (range_m of node {i}) must be >= 0, got {rng_m!r}"
            )
        if rng_m == 0.0:
            raise GeometryError(
                f"measurements[{i}, 0] (range_m of node {i}) is 0: the target would sit at "
                "the node's position, where the measurement model is undefined"
            )
        if abs(omega) > np.pi:
            raise ValidationError(
                f"measurements[{i}, 1] (omega_rad of node {i}) must be in [-pi, pi], "
                f"got {omega!r}"
            )


def validate_frame(
    node_poses: ArrayLike, measurements: ArrayLike, observed: ArrayLike | None = None
) -> tuple[NDArray, NDArray, NDArray | None]:
    """Check one frame's inputs; return ``(poses (N, 3), measurements (N, 3),
    observed (N,) bool or None when every node observed)``.

    Raises :class:`~mmsnap_graph.errors.ValidationError` naming the field and
    value for wrong shapes, NaN or inf in an observed row, a negative range or
    ``|omega| > pi``; :class:`~mmsnap_graph.errors.GeometryError` for a zero
    range (a target at a node).
    """
    poses = _check_poses(node_poses)
    n_nodes = poses.shape[0]
    z = as_float_array(measurements, "measurements")
    if z.shape != (n_nodes, 3):
        raise ValidationError(
            f"measurements must have shape ({n_nodes}, 3) (one (range_m, omega_rad, "
            f"doppler_mps) row per node), got {z.shape}"
        )
    obs = _check_observed(observed, n_nodes)
    # Fast path: one pass of float comparisons (False for NaN); the detailed
    # message only on failure.
    if n_nodes <= 16:
        flags = [True] * n_nodes if obs is None else obs.tolist()
        ok = all(
            0.0 < r < math.inf and -math.pi <= w <= math.pi and -math.inf < v < math.inf
            for (r, w, v), f in zip(z.tolist(), flags)
            if f
        )
    else:
        zo = z if obs is None else z[obs]
        ok = bool(
            np.isfinite(zo).all() and (zo[:, 0] > 0.0).all() and (np.abs(zo[:, 1]) <= np.pi).all()
        )
    if not ok:
        rows = np.arange(n_nodes) if obs is None else np.flatnonzero(obs)
        _check_measurement_rows(z, rows)
    return poses, z, obs


# ---------------------------------------------------------------------------
# Initial values


def initial_states(
    node_poses: ArrayLike,
    measurements: ArrayLike,
    observed: ArrayLike | None = None,
    prior: GaussianPrior | None = None,
    *,
    noise: MeasurementNoise | None = None,
) -> NDArray:
    """Initial values of docs/CONVENTIONS.md for ``F`` frames at once (no validation).

    node_poses : (N, 3) or (F, N, 3) float.
    measurements : (F, N, 3) float; rows of unobserved nodes may hold anything.
    observed : (F, N) bool or None (all observed).
    prior : the prior used as the velocity regularizer, or None.
    noise : sets the Doppler sigma that weighs the Doppler equations against
        the prior (default :class:`MeasurementNoise`).
    Returns (F, 4) float.

    Position: the average of the observed nodes' own detections mapped to the
    global frame (docs/CONVENTIONS.md, the corrected eq. 19). Velocity: the least-squares
    solution of ``V_i = u_i^T v`` with ``u_i`` the line of sight from node i to
    that position, regularized by the prior's velocity part; without a prior
    and with parallel lines of sight (or one node) the minimum-norm solution,
    i.e. the observable radial part only. A frame without observations starts
    at the prior mean (NaN without a prior). A frame whose initial position
    is within 1 nm of an observed node's gets a NaN velocity (its line of
    sight is undefined).
    """
    poses = np.asarray(node_poses, dtype=float)
    z = np.asarray(measurements, dtype=float)
    n_frames, n_nodes = z.shape[:2]
    if observed is None:
        w = np.ones((n_frames, n_nodes))
    else:
        w = np.asarray(observed, dtype=bool).astype(float)
    rng_m = np.where(w > 0, z[..., 0], 0.0)
    omega = np.where(w > 0, z[..., 1], 0.0)
    dop = np.where(w > 0, z[..., 2], 0.0)
    n_obs = w.sum(axis=1)
    det = detection_to_global(rng_m, omega, poses)  # (F, N, 2)
    with np.errstate(invalid="ignore", divide="ignore"):
        pos = np.sum(det * w[..., None], axis=1) / n_obs[:, None]
    node_xy = poses[..., :2]
    d = pos[:, None, :] - node_xy
    dist = np.linalg.norm(d, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        u = np.where(dist < _AT_NODE_M, np.nan, d / dist)
    u = np.where(w[..., None] > 0, u, 0.0)
    # Normal equations of the weighted linear problem (2x2 per frame).
    # Weighted by sigma_V^2 so only the ratio to the prior's sigmas matters.
    a = np.einsum("fn,fni,fnj->fij", w, u, u)
    b = np.einsum("fn,fni,fn->fi", w, u, dop)
    if prior is not None:
        doppler_sigma = (MeasurementNoise() if noise is None else noise).doppler_mps
        reg = (doppler_sigma / prior.sigmas[2:]) ** 2
        a = a + np.diag(reg)
        b = b + reg * prior.mean[2:]
    vel = _solve_2x2_min_norm(a, b)
    state = np.concatenate([pos, vel], axis=1)
    if prior is not None:
        empty = n_obs == 0
        state[empty] = prior.mean
    return state


def _solve_2x2_min_norm(a: NDArray, b: NDArray) -> NDArray:
    """Minimum-norm solutions of symmetric PSD 2x2 systems, (F, 2, 2) and (F, 2).

    Closed-form eigenvalues, the same formula as :func:`_initial_state_scalar`
    (``np.linalg.eigh`` on 2x2 blocks cost the batch solver ~0.85 us/frame).
    """
    a11, a12, a22 = a[:, 0, 0], a[:, 0, 1], a[:, 1, 1]
    b1, b2 = b[:, 0], b[:, 1]
    half_tr = 0.5 * (a11 + a22)
    disc = np.sqrt(0.25 * (a11 - a22) ** 2 + a12 * a12)
    hi = half_tr + disc
    lo = half_tr - disc
    tol = 1e-10 * np.maximum(hi, 1e-300)
    det = a11 * a22 - a12 * a12
    out = np.zeros_like(b)
    with np.errstate(divide="ignore", invalid="ignore"):
        full = lo > tol
        out[:, 0] = np.where(full, (a22 * b1 - a12 * b2) / det, 0.0)
        out[:, 1] = np.where(full, (a11 * b2 - a12 * b1) / det, 0.0)
        # Rank one: project onto the eigenvector of the large eigenvalue.
        rank1 = ~full & (hi > tol)
        if np.any(rank1):
            first = np.abs(hi - a11) >= np.abs(hi - a22)
            e1 = np.where(first, a12, hi - a22)
            e2 = np.where(first, hi - a11, a12)
            norm = np.hypot(e1, e2)
            axis_x = a11 >= a22
            e1 = np.where(norm == 0.0, axis_x.astype(float), e1 / norm)
            e2 = np.where(norm == 0.0, (~axis_x).astype(float), e2 / norm)
            k = (e1 * b1 + e2 * b2) / hi
            out[:, 0] = np.where(rank1, k * e1, out[:, 0])
            out[:, 1] = np.where(rank1, k * e2, out[:, 1])
    bad = ~np.all(np.isfinite(a), axis=(1, 2)) | ~np.all(np.isfinite(b), axis=1)
    out[bad] = np.nan
    return out


def _initial_state_scalar(poses, z, obs, prior, noise) -> list[float]:
    """:func:`initial_states` for one frame in plain floats (the per-frame hot
    path; ``tests/test_oneshot.py`` checks it against the vectorized form)."""
    pl = poses.tolist()
    zl = z.tolist()
    nodes = [i for i in range(len(pl)) if obs is None or obs[i]]
    if not nodes:
        return prior.mean.tolist() if prior is not None else [math.nan] * 4
    sx = sy = 0.0
    for i in nodes:
        px, py, phi = pl[i]
        rng_m, omega = zl[i][0], zl[i][1]
        st = min(max(omega / math.pi, -1.0), 1.0)
        u = rng_m * st
        v = rng_m * math.sqrt(1.0 - st * st)
        c, s = math.cos(phi), math.sin(phi)
        sx += px + u * c - v * s
        sy += py + u * s + v * c
    x = sx / len(nodes)
    y = sy / len(nodes)
    a11 = a12 = a22 = b1 = b2 = 0.0
    for i in nodes:
        dx = x - pl[i][0]
        dy = y - pl[i][1]
        r = math.sqrt(dx * dx + dy * dy)
        if r < _AT_NODE_M:
            return [x, y, math.nan, math.nan]
        ux, uy = dx / r, dy / r
        a11 += ux * ux
        a12 += ux * uy
        a22 += uy * uy
        b1 += ux * zl[i][2]
        b2 += uy * zl[i][2]
    if prior is not None:
        sd = (MeasurementNoise() if noise is None else noise).doppler_mps
        m = prior.mean.tolist()
        ps = prior.sigmas.tolist()
        r1 = (sd / ps[2]) ** 2
        r2 = (sd / ps[3]) ** 2
        a11 += r1
        a22 += r2
        b1 += r1 * m[2]
        b2 += r2 * m[3]
    # Minimum-norm solution of the symmetric 2x2 system (as _solve_2x2_min_norm).
    half_tr = 0.5 * (a11 + a22)
    disc = math.sqrt(0.25 * (a11 - a22) ** 2 + a12 * a12)
    hi = half_tr + disc
    lo = half_tr - disc
    tol = 1e-10 * max(hi, 1e-300)
    if lo > tol:
        det = a11 * a22 - a12 * a12
        return [x, y, (a22 * b1 - a12 * b2) / det, (a11 * b2 - a12 * b1) / det]
    if hi <= tol:
        return [x, y, 0.0, 0.0]
    # Rank one: project onto the eigenvector of the large eigenvalue.
    e1, e2 = (a12, hi - a11) if abs(hi - a11) >= abs(hi - a22) else (hi - a22, a12)
    norm = math.hypot(e1, e2)
    if norm == 0.0:  # diagonal matrix: the eigenvector is an axis
        e1, e2 = (1.0, 0.0) if a11 >= a22 else (0.0, 1.0)
    else:
        e1, e2 = e1 / norm, e2 / norm
    k = (e1 * b1 + e2 * b2) / hi
    return [x, y, k * e1, k * e2]


def _check_initial(initial, poses, obs) -> NDArray:
    x0 = frozen_vector(initial, "initial", 4)
    for i, (px, py, _) in enumerate(poses.tolist()):
        if (obs is None or obs[i]) and math.hypot(x0[0] - px, x0[1] - py) < _AT_NODE_M:
            raise GeometryError(
                f"initial position {x0[:2].tolist()} is at node {i}'s position, where the "
                "measurement model is undefined"
            )
    return x0


def _initial_state_checked(poses, z, obs, prior, noise=None) -> NDArray:
    x0_list = _initial_state_scalar(poses, z, obs, prior, noise)
    x0 = np.array(x0_list)
    if not all(map(math.isfinite, x0_list)):
        raise GeometryError(
            f"initial position {x0[:2].tolist()} (the average of the nodes' detections) "
            "coincides with a node's position, where the lines of sight are undefined"
        )
    return x0


def initial_state(
    node_poses: ArrayLike,
    measurements: ArrayLike,
    observed: ArrayLike | None = None,
    prior: GaussianPrior | None = None,
    *,
    noise: MeasurementNoise | None = None,
) -> NDArray:
    """Initial state of one frame (docs/CONVENTIONS.md, "Initial values"); (4,) float.

    node_poses : (N, 3) float, ``(x_m, y_m, phi_rad)``.
    measurements : (N, 3) float, ``(range_m, omega_rad, doppler_mps)``.
    observed : (N,) bool or None (all observed).
    prior : :class:`GaussianPrior` regularizing the velocity, or None.
    noise : :class:`MeasurementNoise` (its Doppler sigma weighs the prior).

    Raises :class:`~mmsnap_graph.errors.GeometryError` when the average
    detection lands on a node's position (its line of sight is undefined).
    See :func:`initial_states` for the formulas.
    """
    poses, z, obs = validate_frame(node_poses, measurements, observed)
    if (obs is not None and not obs.any()) and prior is None:
        raise ValidationError("observed has no True entry and there is no prior: nothing to start from")
    return _initial_state_checked(poses, z, obs, prior, noise)


# ---------------------------------------------------------------------------
# Graph and solve


@lru_cache(maxsize=64)
def _noise_model(sigmas: tuple[float, float, float], n_nodes: int) -> gtsam.noiseModel.Base:
    return gtsam.noiseModel.Diagonal.Sigmas(np.tile(np.array(sigmas), n_nodes))


@lru_cache(maxsize=64)
def _prior_noise_model(sigmas: tuple[float, ...]) -> gtsam.noiseModel.Base:
    return gtsam.noiseModel.Diagonal.Sigmas(np.array(sigmas))


def _lm_params(max_iterations: int) -> gtsam.LevenbergMarquardtParams:
    params = gtsam.LevenbergMarquardtParams()
    # Converge to rounding: the vectorized batch solver must agree to 1e-6, and
    # Gauss-Newton's quadratic convergence makes the last steps cheap.
    params.setRelativeErrorTol(1e-14)
    params.setAbsoluteErrorTol(1e-14)
    params.setMaxIterations(int(max_iterations))
    # Near-degenerate geometry (configuration C) makes the cost a curved,
    # banana-shaped valley in (x, vx): Doppler measures roughly x * vx there.
    # Marquardt's diagonal scaling and Nielsen's lambda update take ~19 LM
    # iterations on average there instead of ~84 with GTSAM's defaults (and
    # change nothing in benign geometry: ~4).
    params.setDiagonalDamping(True)
    params.setUseFixedLambdaFactor(False)
    return params


_PARAMS_CACHE: dict[int, gtsam.LevenbergMarquardtParams] = {}


def build_frame_graph(
    node_poses: ArrayLike,
    measurements: ArrayLike,
    *,
    observed: ArrayLike | None = None,
    noise: MeasurementNoise = MeasurementNoise(),
    prior: GaussianPrior | None = GaussianPrior(),
    initial: ArrayLike | None = None,
    key: int = STATE_KEY,
) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
    """The one-frame factor graph and its initial values, for users to extend.

    One :func:`~factors.gtsam_factors.frame_measurement_factor` with the
    range, spatial frequency and Doppler of every observed node (error of
    dimension ``3 n_observed``, node after node) and, unless ``prior`` is
    None, a ``PriorFactorVector``, all on the ``Vector4`` state at ``key``.
    Add factors (another target's, a motion model) before optimizing. ``initial``
    (4,) defaults to :func:`initial_state`. Inputs are validated as in
    :func:`fuse_frame`.
    """
    poses, z, obs = validate_frame(node_poses, measurements, observed)
    if initial is None:
        if obs is not None and not obs.any() and prior is None:
            raise ValidationError("observed has no True entry and there is no prior")
        x0 = _initial_state_checked(poses, z, obs, prior, noise)
    else:
        x0 = _check_initial(initial, poses, obs)
    return _build(poses, z, obs, noise, prior, x0, key)


def _build(poses, z, obs, noise, prior, x0, key):
    graph = gtsam.NonlinearFactorGraph()
    if obs is not None:
        poses, z = poses[obs], z[obs]
    n_obs = poses.shape[0]
    if n_obs:
        model = _noise_model((noise.range_m, noise.omega_rad, noise.doppler_mps), n_obs)
        graph.add(frame_measurement_factor(key, poses, z, model))
    if prior is not None:
        graph.add(
            gtsam.PriorFactorVector(key, prior.mean, _prior_noise_model(tuple(prior.sigmas.tolist())))
        )
    values = gtsam.Values()
    values.insert(key, np.asarray(x0, dtype=float))
    return graph, values


def _condition_2x2(a11: float, a12: float, a22: float) -> float:
    half_tr = 0.5 * (a11 + a22)
    disc = math.sqrt(0.25 * (a11 - a22) ** 2 + a12 * a12)
    hi = half_tr + disc
    lo = half_tr - disc
    if not hi > 0.0 or lo <= hi * 1e-15:
        return math.inf
    return hi / lo


def velocity_degeneracy(
    state: ArrayLike, node_poses: ArrayLike, observed: ArrayLike | None = None
) -> float:
    """Condition number of ``sum_i u_i u_i^T`` over the observed nodes' lines
    of sight at ``state`` (>= 1; inf when singular); see
    :attr:`FusionResult.degeneracy`. No validation.

    state : (4,) float; node_poses : (N, 3) float; observed : (N,) bool or None.
    """
    s = np.asarray(state, dtype=float).tolist()
    poses = np.asarray(node_poses, dtype=float).tolist()
    obs = None if observed is None else np.asarray(observed, dtype=bool).tolist()
    a11 = a12 = a22 = 0.0
    for i, (px, py, _) in enumerate(poses):
        if obs is not None and not obs[i]:
            continue
        dx = s[0] - px
        dy = s[1] - py
        r2 = dx * dx + dy * dy
        if r2 == 0.0:
            return math.inf
        a11 += dx * dx / r2
        a12 += dx * dy / r2
        a22 += dy * dy / r2
    return _condition_2x2(a11, a12, a22)


def _residuals_and_degeneracy(state, poses, z, obs, noise, prior):
    """Whitened residuals (N, 3), the degeneracy and the gradient (4,) of the
    cost ``0.5 * sum of squared whitened residuals`` (prior included) at
    ``state``, in one pass of :func:`factors.models.measurement_model_scalar`."""
    x, y, vx, vy = state.tolist()
    sigmas = (noise.range_m, noise.omega_rad, noise.doppler_mps)
    out = []
    zl = z.tolist()
    a11 = a12 = a22 = 0.0
    grad = [0.0, 0.0, 0.0, 0.0]
    for i, (px, py, phi) in enumerate(poses.tolist()):
        if obs is not None and not obs[i]:
            out.append((math.nan, math.nan, math.nan))
            continue
        try:
            r, w, v, jac = measurement_model_scalar(x, y, vx, vy, px, py, math.cos(phi), math.sin(phi))
        except ZeroDivisionError:
            out.append((math.nan, math.nan, math.nan))
            a11 = a22 = math.nan
            grad = [math.nan] * 4
            continue
        zi = zl[i]
        e = (
            (r - zi[0]) / sigmas[0],
            wrap_angle_scalar(w - zi[1]) / sigmas[1],
            (v - zi[2]) / sigmas[2],
        )
        out.append(e)
        for k in range(3):
            ek = e[k] / sigmas[k]
            for j in range(4):
                grad[j] += jac[4 * k + j] * ek
        ux, uy = jac[10], jac[11]
        a11 += ux * ux
        a12 += ux * uy
        a22 += uy * uy
    if prior is not None:
        m = prior.mean.tolist()
        ps = prior.sigmas.tolist()
        for j, xj in enumerate((x, y, vx, vy)):
            grad[j] += (xj - m[j]) / ps[j] ** 2
    degeneracy = _condition_2x2(a11, a12, a22) if math.isfinite(a11) else math.inf
    return np.array(out), degeneracy, np.array(grad)


def fuse_frame(
    node_poses: ArrayLike,
    measurements: ArrayLike,
    *,
    observed: ArrayLike | None = None,
    noise: MeasurementNoise = MeasurementNoise(),
    prior: GaussianPrior | None = GaussianPrior(),
    covariance: Literal["laplace", "grid", "both"] = "laplace",
    initial: ArrayLike | None = None,
    max_iterations: int = 500,
    grid_points_per_axis: int = 21,
    grid_half_width_sigmas: float = 5.0,
) -> FusionResult:
    """Bayesian (or ML) one-shot fusion of one frame (paper eqs. 15-18).

    Parameters
    ----------
    node_poses : (N, 3) float
        Node poses ``(x_m, y_m, phi_rad)`` in the global frame (N >= 1).
    measurements : (N, 3) float
        ``(range_m, omega_rad, doppler_mps)`` per node; rows of nodes with
        ``observed[i] = False`` are ignored (they may be NaN).
    observed : (N,) bool, optional
        Which nodes saw the target (default: all).
    noise : MeasurementNoise
        Measurement sigmas (default: the paper's).
    prior : GaussianPrior or None
        The Gaussian prior (MAP, default the paper's); None for ML.
    covariance : {"laplace", "grid", "both"}
        ``"laplace"``: ``gtsam.Marginals`` only. ``"grid"`` / ``"both"``:
        also the paper's numerical posterior covariance on a 4D grid
        (``result.grid_covariance``); the Laplace covariance is always
        computed, since the grid is laid out along it.
    initial : (4,) float, optional
        Starting state (default: :func:`initial_state`).
    max_iterations : int
        Levenberg-Marquardt iteration limit; reaching it is a failure.
    grid_points_per_axis, grid_half_width_sigmas :
        Grid layout, see :func:`mmsnap_graph.fusion.grid.grid_posterior`.

    Returns
    -------
    FusionResult
        ``success=False`` with a message when the system is indeterminate,
        LM does not converge or GTSAM raises; never raises for those.

    Raises
    ------
    ValidationError, GeometryError
        Invalid input (see :func:`validate_frame`), or an initial position
        (given, or from the detections) on an observed node.
    """
    if covariance not in ("laplace", "grid", "both"):
        raise ValidationError(
            f"covariance must be 'laplace', 'grid' or 'both', got {covariance!r}"
        )
    if not isinstance(noise, MeasurementNoise):
        raise ValidationError(f"noise must be a MeasurementNoise, got {type(noise).__name__}")
    if prior is not None and not isinstance(prior, GaussianPrior):
        raise ValidationError(f"prior must be a GaussianPrior or None, got {type(prior).__name__}")
    max_iterations = int(max_iterations)
    if max_iterations < 1:
        raise ValidationError(f"max_iterations must be >= 1, got {max_iterations}")
    poses, z, obs = validate_frame(node_poses, measurements, observed)
    n_nodes = poses.shape[0]
    n_observed = n_nodes if obs is None else int(obs.sum())

    def fail(message, state=None, x0=None, iterations=0, cost=math.nan):
        nan4 = np.full(4, np.nan)
        nan44 = np.full((4, 4), np.nan)
        return FusionResult(
            state=nan4 if state is None else state,
            covariance=nan44,
            success=False,
            message=message,
            iterations=iterations,
            final_cost=float(cost),
            whitened_residuals=np.full((n_nodes, 3), np.nan),
            degeneracy=math.inf,
            grid_covariance=None if covariance == "laplace" else nan44,
            initial_state=nan4 if x0 is None else x0,
            n_observed=n_observed,
            used_prior=prior is not None,
        )

    if n_observed == 0 and prior is None:
        return fail("no node observed the target and there is no prior: the state is indeterminate")
    if initial is None:
        x0 = _initial_state_checked(poses, z, obs, prior, noise)
    else:
        x0 = _check_initial(initial, poses, obs)

    graph, values = _build(poses, z, obs, noise, prior, x0, STATE_KEY)
    params = _PARAMS_CACHE.get(max_iterations)
    if params is None:
        params = _PARAMS_CACHE.setdefault(max_iterations, _lm_params(max_iterations))
    try:
        optimizer = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
        solution = optimizer.optimize()
    except Exception as exc:  # GTSAM (or a callback) raised: flag the frame
        return fail(f"Levenberg-Marquardt failed: {type(exc).__name__}: {exc}", x0=x0)
    iterations = int(optimizer.iterations())
    state = solution.atVector(STATE_KEY)
    cost = float(optimizer.error())
    if not (math.isfinite(cost) and np.isfinite(state).all()):
        return fail("Levenberg-Marquardt diverged to a non-finite state", state, x0, iterations, cost)
    if iterations >= max_iterations:
        return fail(
            f"Levenberg-Marquardt did not converge within max_iterations={max_iterations}",
            state,
            x0,
            iterations,
            cost,
        )
    try:
        cov = gtsam.Marginals(graph, solution).marginalCovariance(STATE_KEY)
    except Exception as exc:
        return fail(
            "indeterminate linear system at the solution, no covariance "
            f"({type(exc).__name__}: {exc})",
            state,
            x0,
            iterations,
            cost,
        )
    cov = 0.5 * (cov + cov.T)
    messages = ["converged"]
    success = True
    if not (np.isfinite(cov).all() and (cov.diagonal() > 0.0).all()):
        success = False
        messages = ["the Laplace covariance is not positive definite"]
    whitened, degeneracy, grad = _residuals_and_degeneracy(state, poses, z, obs, noise, prior)
    # A stationarity check independent of LM's stopping rule: the squared
    # Newton decrement g^T S g is the cost decrease one more Gauss-Newton
    # step would bring (~1e-15 at convergence; LM can also stop because it
    # "cannot decrease the error" away from a minimum).
    decrement = float(grad @ cov @ grad) if success else 0.0
    if not decrement <= NEWTON_DECREMENT_TOLERANCE:
        success = False
        messages = [
            f"Levenberg-Marquardt stopped away from a minimum (squared Newton decrement "
            f"{decrement:.3g} > {NEWTON_DECREMENT_TOLERANCE:g})"
        ]
    if degeneracy > DEGENERACY_THRESHOLD:
        messages.append(
            f"degenerate geometry: velocity condition number {degeneracy:.3g} "
            f"> {DEGENERACY_THRESHOLD:g}, the cross-line velocity rests on the prior"
            if prior is not None
            else f"degenerate geometry: velocity condition number {degeneracy:.3g} "
            f"> {DEGENERACY_THRESHOLD:g}, the ML velocity is unreliable"
        )
    grid_cov = None
    if covariance != "laplace":
        if success:
            from .grid import grid_posterior

            grid = grid_posterior(
                state,
                poses,
                z,
                observed=obs,
                noise=noise,
                prior=prior,
                scale_covariance=cov,
                points_per_axis=grid_points_per_axis,
                half_width_sigmas=grid_half_width_sigmas,
            )
            grid_cov = grid.covariance
            if grid.message:
                messages.append(grid.message)
        else:
            grid_cov = np.full((4, 4), np.nan)
    for arr in (state, cov, whitened, x0):
        arr.setflags(write=False)  # handed over without a copy
    return FusionResult(
        state=state,
        covariance=cov,
        success=success,
        message="; ".join(messages),
        iterations=iterations,
        final_cost=cost,
        whitened_residuals=whitened,
        degeneracy=degeneracy,
        grid_covariance=grid_cov,
        initial_state=x0,
        n_observed=n_observed,
        used_prior=prior is not None,
    )
