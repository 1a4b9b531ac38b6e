"""Cramer-Rao bounds of one-shot fusion, from the same Jacobians as the factors.

For Gaussian measurement noise the Fisher information of the state at
``theta`` is

.. math::

    I(\\theta) = \\sum_i J_i(\\theta)^T W J_i(\\theta), \\qquad
    W = \\mathrm{diag}(1/\\sigma_R^2, 1/\\sigma_\\Omega^2, 1/\\sigma_V^2),

summed over the nodes that observe the target, with ``J_i`` from
:func:`factors.models.measurement_model`. The ML (Cramer-Rao) bound is
``I^{-1}``; the Bayesian bound used here adds the Gaussian prior's information,
``(I(theta) + P)^{-1}`` with ``P = diag(1 / s^2)``: the Van Trees bound for a
posterior concentrated where ``I`` is nearly constant (the one-shot case: the
measurement information exceeds the prior's by orders of magnitude except in
the degenerate direction). It is also the Laplace covariance evaluated at the
true state.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from factors.models import measurement_model

from ..errors import GeometryError, ValidationError
from .._validation import frozen_vector
from ..data.noise import GaussianPrior, MeasurementNoise
from .problem import check_observed, check_noise, check_poses

__all__ = ["fisher_information", "cramer_rao_bound", "bayesian_bound"]


def _inputs(state, node_poses, noise, observed):
    x = frozen_vector(state, "state", 4)
    poses = check_poses(node_poses)
    check_noise(noise)
    obs = check_observed(observed, poses.shape[0])
    if obs is not None:
        poses = poses[obs]
    r = np.hypot(*(x[:2] - poses[:, :2]).T) if poses.size else np.zeros(0)
    if np.any(r == 0.0):
        i = int(np.flatnonzero(r == 0.0)[0])
        raise GeometryError(f"state position {x[:2].tolist()} is at observed node {i}'s position")
    return x, poses


def fisher_information(
    state: ArrayLike,
    node_poses: ArrayLike,
    noise: MeasurementNoise = MeasurementNoise(),
    observed: ArrayLike | None = None,
) -> NDArray:
    """Fisher information of ``(x, y, vx, vy)`` from the observed nodes.

    state : (4,) float, the true state.
    node_poses : (N, 3) float.
    noise : MeasurementNoise.
    observed : (N,) bool or None (all).
    Returns (4, 4) float (zero when no node observes).
    """
    x, poses = _inputs(state, node_poses, noise, observed)
    if poses.shape[0] == 0:
        return np.zeros((4, 4))
    _, jac = measurement_model(x, poses)  # (N, 3, 4)
    wj = jac / noise.sigmas[:, None] ** 2
    info = np.einsum("nki,nkj->ij", jac, wj)
    return 0.5 * (info + info.T)


def _inverse(info: NDArray, what: str) -> NDArray:
    eig = np.linalg.eigvalsh(info)
    if eig[0] <= eig[-1] * 1e-14:
        cond = np.inf if eig[0] <= 0 else eig[-1] / eig[0]
        raise GeometryError(
            f"{what} is singular (condition number {cond:.3g}): the state is not "
            "observable from these nodes; use bayesian_bound with a prior"
        )
    chol = np.linalg.cholesky(info)
    inv_chol = np.linalg.solve(chol, np.eye(4))
    cov = inv_chol.T @ inv_chol
    return 0.5 * (cov + cov.T)


def cramer_rao_bound(
    state: ArrayLike,
    node_poses: ArrayLike,
    noise: MeasurementNoise = MeasurementNoise(),
    observed: ArrayLike | None = None,
) -> NDArray:
    """Cramer-Rao bound of an unbiased (ML) estimate, ``I(theta)^{-1}``; (4, 4).

    Raises :class:`~mmsnap_graph.errors.GeometryError` when the Fisher
    information is singular (one node, or a target exactly on the line
    through two radars: the cross-line velocity is unobservable).
    """
    return _inverse(fisher_information(state, node_poses, noise, observed), "the Fisher information")


def bayesian_bound(
    state: ArrayLike,
    node_poses: ArrayLike,
    noise: MeasurementNoise = MeasurementNoise(),
    prior: GaussianPrior = GaussianPrior(),
    observed: ArrayLike | None = None,
) -> NDArray:
    """Bayesian bound with the Gaussian prior, ``(I(theta) + P)^{-1}``; (4, 4).

    ``P = diag(1 / prior.sigmas^2)``. Always finite, since the prior is proper.
    """
    if not isinstance(prior, GaussianPrior):
        raise ValidationError(f"prior must be a GaussianPrior, got {type(prior).__name__}")
    info = fisher_information(state, node_poses, noise, observed) + prior.information
    return _inverse(info, "the posterior information")
