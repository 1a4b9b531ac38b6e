"""The paper's numerical posterior covariance: the posterior density on a 4D
grid around the MAP (paper Sec. III-B, "Covariance Estimation").

The grid is laid out along the Laplace covariance ``S = L L^T``:
``theta = theta_hat + L xi`` with ``xi`` on a regular grid over
``[-k, k]^4`` (``k = half_width_sigmas``). A grid aligned with the state axes
under-resolves the strong position-velocity correlations of a one-shot
posterior; in the whitened coordinates a Gaussian posterior is round and a
spacing of half a sigma integrates it to far better than a percent. The map is
linear, so its Jacobian is a constant and cancels in the normalization.

The unnormalized log posterior is evaluated with
:func:`factors.models.predict_measurements` (the prediction of
:func:`factors.models.measurement_model` without its Jacobian) over all grid
points at once (in chunks, to bound memory); the covariance is the weighted second moment about
the grid posterior mean. When the density on the grid's faces is not
negligible (a posterior much wider than its Laplace approximation, as in a
degenerate geometry), the grid is widened and evaluated again.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from factors.models import predict_measurements, residual

from ..data.noise import GaussianPrior, MeasurementNoise
from ..errors import ValidationError

__all__ = ["GridPosterior", "grid_posterior", "neg_log_posterior"]

#: Density on the grid faces, relative to the peak, above which the grid is widened.
EDGE_DENSITY_TOLERANCE = 1e-4

#: Grid points evaluated at a time (whole 3D slices): their temporaries stay
#: in cache.
GRID_CHUNK_POINTS = 100_000


@dataclass(frozen=True, kw_only=True, slots=True)
class GridPosterior:
    """The grid posterior's moments.

    mean : (4,) float, posterior mean on the grid.
    covariance : (4, 4) float, posterior covariance about ``mean``.
    edge_density : float, largest density on the grid's faces relative to the
        largest density on the grid (small means nothing was cut off).
    half_width_sigmas : float, the half-width finally used (Laplace sigmas).
    n_points : int, grid points evaluated in the final grid.
    message : str, empty, or a warning that the grid still truncates the posterior.
    """

    mean: NDArray
    covariance: NDArray
    edge_density: float
    half_width_sigmas: float
    n_points: int
    message: str


def neg_log_posterior(
    states: ArrayLike,
    node_poses: ArrayLike,
    measurements: ArrayLike,
    *,
    observed: ArrayLike | None,
    sigmas: ArrayLike,
    prior_mean: ArrayLike | None,
    prior_sigmas: ArrayLike | None,
) -> NDArray:
    """``0.5 * sum of squared whitened residuals`` (paper eq. 18 halved) at
    many states: ``states (..., 4)`` -> ``(...,)``; no validation.

    node_poses : (N, 3); measurements : (N, 3); observed : (N,) bool or None;
    sigmas : (3,); prior_mean, prior_sigmas : (4,) or None (ML).
    """
    states = np.asarray(states, dtype=float)
    poses = np.asarray(node_poses, dtype=float)
    z = np.asarray(measurements, dtype=float)
    if observed is not None:
        keep = np.asarray(observed, dtype=bool)
        poses, z = poses[keep], z[keep]
    sig = np.asarray(sigmas, dtype=float)
    cost = np.zeros(states.shape[:-1])
    for pose, meas in zip(poses, z):
        e = residual(predict_measurements(states, pose), meas) / sig
        cost += 0.5 * np.sum(e * e, axis=-1)
    if prior_mean is not None:
        e = (states - np.asarray(prior_mean, dtype=float)) / np.asarray(prior_sigmas, dtype=float)
        cost += 0.5 * np.sum(e * e, axis=-1)
    return cost


def _moments(center, chol, axis, kw, chunk_size):
    """Grid moments in whitened coordinates: ``(mean_xi (4,), cov_xi (4, 4),
    edge density, n points)``, or None if the posterior is nowhere finite."""
    n = axis.size
    # theta = center + L xi over the grid, built by broadcasting: the last
    # three axes' contribution once, the first axis chunk by chunk.
    rest = (
        axis[:, None, None, None] * chol[:, 1]
        + axis[None, :, None, None] * chol[:, 2]
        + axis[None, None, :, None] * chol[:, 3]
    )  # (n, n, n, 4)
    cost = np.empty((n, n, n, n))
    rows = max(1, int(chunk_size) // n**3)
    for start in range(0, n, rows):
        a = axis[start : start + rows]
        states = center + a[:, None, None, None, None] * chol[:, 0] + rest[None]
        cost[start : start + rows] = neg_log_posterior(states, **kw)
    finite = np.isfinite(cost)
    if not finite.any():
        return None
    w = np.exp(-(np.where(finite, cost, np.inf) - cost[finite].min()))
    total = w.sum()
    # Moments of a separable grid from marginal sums of the weights.
    axes = range(4)
    w1 = [w.sum(axis=tuple(j for j in axes if j != k)) for k in axes]
    mean_xi = np.array([axis @ w1[k] for k in axes]) / total
    second = np.empty((4, 4))
    for k in axes:
        second[k, k] = (axis * axis) @ w1[k] / total
        for m in range(k + 1, 4):
            w2 = w.sum(axis=tuple(j for j in axes if j not in (k, m)))  # (n, n)
            second[k, m] = second[m, k] = axis @ w2 @ axis / total
    cov_xi = second - np.outer(mean_xi, mean_xi)
    faces = [np.take(w, idx, axis=ax).max() for ax in axes for idx in (0, n - 1)]
    return mean_xi, cov_xi, float(max(faces) / w.max()), n**4


def grid_posterior(
    state: ArrayLike,
    node_poses: ArrayLike,
    measurements: ArrayLike,
    *,
    observed: ArrayLike | None = None,
    noise: MeasurementNoise = MeasurementNoise(),
    prior: GaussianPrior | None = GaussianPrior(),
    scale_covariance: ArrayLike,
    points_per_axis: int = 21,
    half_width_sigmas: float = 5.0,
    max_widenings: int = 2,
) -> GridPosterior:
    """Posterior mean and covariance on a 4D grid around ``state``.

    Parameters
    ----------
    state : (4,) float
        Grid centre (the MAP or ML estimate).
    node_poses, measurements : (N, 3) float
        As in a :class:`~mmsnap_graph.fusion.frame_problem.FrameProblem` (already validated).
    observed : (N,) bool or None
    noise : :class:`~mmsnap_graph.data.noise.MeasurementNoise` (default the paper's)
    prior : :class:`~mmsnap_graph.data.noise.GaussianPrior` (default the paper's) or None (ML)
    scale_covariance : (4, 4) float, positive definite
        The grid's shape, normally the Laplace covariance.
    points_per_axis : int, odd >= 5
        ``n``; the grid has ``n^4`` points (21 -> 194,481).
    half_width_sigmas : float
        ``k``: the grid spans ``+-k`` along each whitened axis.
    max_widenings : int
        How many times the grid may double its half-width when the density on
        its faces exceeds ``EDGE_DENSITY_TOLERANCE`` of the peak.

    Returns
    -------
    GridPosterior
    """
    n = int(points_per_axis)
    if n < 5 or n % 2 == 0:
        raise ValidationError(f"points_per_axis must be odd and >= 5, got {points_per_axis!r}")
    k = float(half_width_sigmas)
    if not (np.isfinite(k) and k > 0):
        raise ValidationError(f"half_width_sigmas must be finite and > 0, got {half_width_sigmas!r}")
    scale = np.asarray(scale_covariance, dtype=float)
    if scale.shape != (4, 4) or not np.isfinite(scale).all():
        raise ValidationError(f"scale_covariance must be a finite (4, 4) matrix, got shape {scale.shape}")
    try:
        chol = np.linalg.cholesky(0.5 * (scale + scale.T))
    except np.linalg.LinAlgError as exc:
        raise ValidationError("scale_covariance must be positive definite") from exc
    center = np.asarray(state, dtype=float)
    kw = dict(
        node_poses=node_poses,
        measurements=measurements,
        observed=observed,
        sigmas=noise.sigmas,
        prior_mean=None if prior is None else prior.mean,
        prior_sigmas=None if prior is None else prior.sigmas,
    )
    widenings = int(max_widenings)
    while True:
        result = _moments(center, chol, np.linspace(-k, k, n), kw, GRID_CHUNK_POINTS)
        if result is None or result[2] <= EDGE_DENSITY_TOLERANCE or widenings <= 0:
            break
        widenings -= 1
        k *= 2.0
    if result is None:
        nan = np.full(4, np.nan)
        return GridPosterior(
            mean=nan,
            covariance=np.full((4, 4), np.nan),
            edge_density=np.nan,
            half_width_sigmas=k,
            n_points=n**4,
            message="grid posterior: the posterior is not finite anywhere on the grid",
        )
    mean_xi, cov_xi, edge, n_points = result
    cov = chol @ cov_xi @ chol.T
    message = ""
    if edge > EDGE_DENSITY_TOLERANCE:
        message = (
            f"grid posterior truncated: density {edge:.2g} of the peak on the grid's faces "
            f"at +-{k:g} Laplace sigmas"
        )
    return GridPosterior(
        mean=center + chol @ mean_xi,
        covariance=0.5 * (cov + cov.T),
        edge_density=edge,
        half_width_sigmas=k,
        n_points=n_points,
        message=message,
    )
