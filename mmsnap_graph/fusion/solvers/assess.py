"""Assessing a solved one-shot frame (no GTSAM): whitened residuals, the
velocity degeneracy, the gradient of the cost and the checks that make a
:class:`~mmsnap_graph.data.solution.FusionSolution` frame a success (a positive-definite
covariance, a vanishing Newton decrement); used by
:mod:`mmsnap_graph.fusion.solvers.gtsam_graph`. Each node has its own sigmas (a sequence of
N :class:`~mmsnap_graph.data.noise.MeasurementNoise`).
"""

from __future__ import annotations

import math

import numpy as np

from factors.models import measurement_model_scalar, wrap_angle_scalar

from ...data.results import DEGENERACY_THRESHOLD, Status
from ..problem import condition_2x2

__all__ = [
    "NEWTON_DECREMENT_TOLERANCE",
    "residuals_and_degeneracy",
    "kernel_weight",
    "positive_definite",
    "assess_fit",
]

#: Largest squared Newton decrement ``g^T S g`` (cost units) accepted at a
#: solution; converged frames show ~1e-15 (1e-12 in configuration C).
NEWTON_DECREMENT_TOLERANCE = 1e-8


def _sigmas(noise):
    return (noise.range_m, noise.omega_rad, noise.doppler_mps)


def residuals_and_degeneracy(state, poses, z, obs, noise, prior, kernel=None):
    """Whitened residuals (N, 3), the degeneracy and the gradient (4,) of the
    cost ``0.5 * sum of squared whitened residuals`` (prior included; each
    node weighted by ``kernel``'s IRLS weight) at ``state``, in one pass of
    :func:`factors.models.measurement_model_scalar`."""
    x, y, vx, vy = state.tolist()
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
        sigmas = _sigmas(noise[i])
        e = (
            (r - zi[0]) / sigmas[0],
            wrap_angle_scalar(w - zi[1]) / sigmas[1],
            (v - zi[2]) / sigmas[2],
        )
        out.append(e)
        wt = 1.0 if kernel is None else kernel_weight(kernel, e[0] ** 2 + e[1] ** 2 + e[2] ** 2)
        for k in range(3):
            ek = wt * e[k] / sigmas[k]
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
    degeneracy = condition_2x2(a11, a12, a22) if math.isfinite(a11) else math.inf
    return np.array(out), degeneracy, np.array(grad)


def kernel_weight(kernel, s2: float) -> float:
    """The IRLS weight of GTSAM's Huber or Cauchy kernel at squared norm ``s2``
    (as :func:`~.robust.kernel_weight_and_loss`)."""
    name, k = kernel
    if name == "huber":
        s = math.sqrt(s2)
        return 1.0 if s <= k else k / s
    return 1.0 / (1.0 + s2 / (k * k))


#: Smallest ``min / max`` eigenvalue ratio of a covariance reported as success:
#: below it the smallest eigenvalues are rounding noise.
_MIN_EIGENVALUE_RATIO = 1e-13


def positive_definite(cov) -> bool:
    """Finite and positive definite to rounding: a Cholesky factorization whose
    squared pivots all exceed ``_MIN_EIGENVALUE_RATIO`` times the largest
    diagonal entry (cheaper than a 4x4 eigendecomposition)."""
    try:
        lo = np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        return False
    diag = cov.diagonal()
    pivots = lo.diagonal()
    return bool(np.isfinite(lo).all() and (pivots * pivots).min() > _MIN_EIGENVALUE_RATIO * diag.max())


def assess_fit(state, cov, poses, z, obs, noise, prior, kernel=None):
    """Check the solution: ``(status, messages, whitened residuals, degeneracy)``."""
    status, messages = Status.OK, ["converged"]
    if not positive_definite(cov):
        status, messages = Status.SINGULAR, ["the Laplace covariance is not positive definite"]
    whitened, degeneracy, grad = residuals_and_degeneracy(state, poses, z, obs, noise, prior, kernel)
    # A stationarity check independent of LM's stopping rule: the squared
    # Newton decrement g^T S g is the cost decrease one more Gauss-Newton
    # step would bring (~1e-15 at convergence; LM can also stop because it
    # "cannot decrease the error" away from a minimum).
    decrement = float(grad @ cov @ grad) if status == Status.OK else 0.0
    if not decrement <= NEWTON_DECREMENT_TOLERANCE:
        # Code 3, as the /fused files have always stored it.
        status = Status.NON_FINITE
        messages = [
            f"Levenberg-Marquardt stopped away from a minimum (squared Newton decrement "
            f"{decrement:.3g} > {NEWTON_DECREMENT_TOLERANCE:g})"
        ]
    if degeneracy > DEGENERACY_THRESHOLD:
        messages.append(
            f"degenerate geometry: velocity condition number {degeneracy:.3g} "
            f"> {DEGENERACY_THRESHOLD:g}, "
            + ("the cross-line velocity rests on the prior" if prior is not None
               else "the ML velocity is unreliable")
        )
    return status, messages, whitened, degeneracy
