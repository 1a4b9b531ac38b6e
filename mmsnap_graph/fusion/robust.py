"""Robust one-shot fusion: the residual gate and the robust kernels
(docs/CONVENTIONS.md, "One-shot fusion").

What :func:`mmsnap_graph.fusion.solve.robust_solve` (the robust fit around
any solver) and the recording's checks share, GTSAM-free:

- ``robust="gate"``: after the fit, each observed node's whitened residual
  3-vector ``e_i`` is tested, ``|e_i|^2 > chi2.ppf(p, 3)``
  (:func:`residual_gate_threshold`, ``p`` =
  :data:`RESIDUAL_GATE_PROBABILITY` by default). A frame with a failing node
  is refitted without each node in turn (only while at least two nodes stay,
  so that the rest can still be tested); the passing refit of lowest cost is
  kept and its left-out node reported ``rejected``; a frame no single removal
  repairs is flagged ``Status.RESIDUAL_TEST_FAILED``.
- ``robust="huber"`` / ``"cauchy"``: GTSAM's m-estimators on each node's
  whitened 3-vector (:func:`kernel_weight_and_loss`; constants
  :data:`factors.robust.ROBUST_K_DEFAULT`); nodes whose residual fails the
  gate are reported ``rejected`` (down-weighted, not removed).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from numpy.typing import NDArray

from factors.robust import robust_k as kernel_constant

from ..errors import ValidationError
from .._validation import chi2_gate

__all__ = [
    "ROBUST_CHOICES",
    "RESIDUAL_GATE_PROBABILITY",
    "check_robust",
    "check_robust_k",
    "residual_gate_threshold",
    "kernel_weight_and_loss",
    "node_d2",
]

#: The robust options of the one-shot estimators (None: plain least squares).
ROBUST_CHOICES = ("gate", "huber", "cauchy")

#: Default probability of the per-node residual gate: a node whose squared
#: whitened residual 3-vector exceeds ``chi2.ppf(p, 3)`` after the fit fails.
RESIDUAL_GATE_PROBABILITY = 0.999


def check_robust(robust: object) -> str | None:
    """``robust`` if it is None or one of :data:`ROBUST_CHOICES`; ValidationError otherwise."""
    if robust is not None and robust not in ROBUST_CHOICES:
        raise ValidationError(f"robust must be None, 'gate', 'huber' or 'cauchy', got {robust!r}")
    return robust


def check_robust_k(robust: str, robust_k: object) -> float:
    """The kernel constant: ``robust_k`` (finite, > 0) or the kernel's default."""
    if robust_k is not None and (isinstance(robust_k, (bool, np.bool_))
                                 or not isinstance(robust_k, (int, float, np.integer, np.floating))):
        raise ValidationError(f"robust_k must be a number, got {robust_k!r}")
    k = kernel_constant(robust, robust_k)
    if not (np.isfinite(k) and k > 0):
        raise ValidationError(f"robust_k must be finite and > 0, got {robust_k!r}")
    return k


@lru_cache(maxsize=16)
def residual_gate_threshold(probability: float) -> float:
    """``chi2.ppf(probability, 3)``; ValidationError unless ``0 < probability < 1``."""
    return chi2_gate(probability, 3, name="residual_gate_probability")


def node_d2(residuals: NDArray) -> NDArray:
    """``(..., N)`` squared norms of whitened residual 3-vectors ``(..., N, 3)``, 0 where NaN."""
    r = np.asarray(residuals, dtype=float)
    return np.nan_to_num(np.einsum("...k,...k->...", r, r), nan=0.0)


def kernel_weight_and_loss(name: str, k: float, s2: NDArray) -> tuple[NDArray, NDArray]:
    """IRLS weight and loss of GTSAM's ``mEstimator`` ``Huber`` or ``Cauchy``
    with constant ``k`` at squared whitened norms ``s2``: Huber weight
    ``min(1, k / s)``, loss ``s^2 / 2`` or ``k s - k^2 / 2``; Cauchy weight
    ``1 / (1 + s^2 / k^2)``, loss ``k^2 / 2 log(1 + s^2 / k^2)``."""
    if name == "huber":
        s = np.sqrt(s2)
        inside = s <= k
        with np.errstate(divide="ignore", invalid="ignore"):
            weight = np.where(inside, 1.0, k / s)
        loss = np.where(inside, 0.5 * s2, k * s - 0.5 * k * k)
    else:
        q = s2 / (k * k)
        weight = 1.0 / (1.0 + q)
        loss = 0.5 * k * k * np.log1p(q)
    return weight, loss




@lru_cache(maxsize=64)
def _total_threshold(probability: float, dof: int) -> float:
    return chi2_gate(probability, dof, name="residual_gate_probability")


def residual_test_fails(residuals: NDArray, probability: float) -> NDArray:
    """The residual test of ``robust="gate"`` on whitened residuals
    ``(..., N, 3)`` (NaN rows: nodes not used): True where a node's squared
    norm exceeds ``chi2.ppf(p, 3)`` or where the sum over the ``n`` nodes
    used exceeds ``chi2.ppf(p, max(3 n - 4, 1))`` (the frame's degrees of
    freedom: ``3 n`` measurements, 4 states)."""
    r = np.asarray(residuals, dtype=float)
    d2 = node_d2(r)
    n_used = np.sum(~np.isnan(r[..., 0]), axis=-1)
    node = (d2 > residual_gate_threshold(probability)).any(axis=-1)
    dof = np.maximum(3 * n_used - 4, 1)
    total_thr = np.vectorize(lambda d: _total_threshold(float(probability), int(d)), otypes=[float])(dof)
    return node | (d2.sum(axis=-1) > total_thr)
