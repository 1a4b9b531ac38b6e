"""Frame-to-frame correlation of calibration residuals: an effective sample size.

A least-squares pose estimate ``xi = H^{-1} sum_t g_t`` (``g_t`` the score of
frame ``t``: ``A_t^T e_t``, summed over every residual of that frame) has the
covariance ``H^{-1} Omega H^{-1}`` with ``Omega`` the *long-run* covariance of
the scores,

.. math::

    \\Omega = \\sum_t \\sum_s \\mathrm{Cov}(g_t, g_s)
            = \\Gamma_0 + \\sum_{l \\ge 1} (\\Gamma_l + \\Gamma_l^T),
    \\quad \\Gamma_l = \\sum_t g_t g_{t+l}^T .

Treating frames as independent keeps ``Gamma_0`` only. EKF tracks are smooth:
their errors are strongly autocorrelated (0.6-0.9 at lag 1), and ``Omega`` is
then several times ``Gamma_0``: the pose sigma comes out several times too
small (two halves of one recording disagreed by 5.3 degrees against a
reported 0.8-1.5).

:func:`autocorrelation_factor` estimates the integrated autocorrelation time
``tau = Omega / Gamma_0`` (averaged over the score components after whitening
them by ``Gamma_0``; ``K / tau`` is the effective number of frames) by
Andrews and Monahan's prewhitened estimator: an AR(1) coefficient ``rho``
(the mean lag-1 autocorrelation of the whitened scores), the Bartlett
(Newey-West) long-run variance of the prewhitened series ``u_t = g_t - rho
g_{t-1}`` with bandwidth ``ceil(4 (T / 100)^{2/9})``, recoloured by ``1 / (1 -
rho)^2``. The AR(1) part carries the strong short-range persistence that a
bare Bartlett window with a small bandwidth underestimates; the Bartlett part
corrects what the AR(1) model misses. Frames missing from the series (gaps
between track fragments) count as zero scores; gaps longer than
:data:`MAX_GAP_FRAMES` are shortened to it (the series is uncorrelated across
them anyway). The factor is never below 1: residuals anticorrelated by chance
do not shrink the covariance.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..._validation import frame_steps

__all__ = ["autocorrelation_factor", "MAX_AR_COEFFICIENT", "MAX_GAP_FRAMES"]

#: Largest AR(1) coefficient used (tau at most (1 + r) / (1 - r) ~ 65 from the
#: AR part): beyond it a few hundred frames cannot tell persistence from drift.
MAX_AR_COEFFICIENT = 0.97
#: Gaps between frames longer than this are shortened to it.
MAX_GAP_FRAMES = 64


def _frame_sums(scores: NDArray, times: NDArray) -> tuple[NDArray, int]:
    """Scores summed per time, on a dense zero-filled time axis ``(T, p)``,
    and the number of distinct times."""
    steps = frame_steps(times)  # not np.diff: frames at both ends of int64
    if (steps == 1).all():  # the usual case: one row per consecutive frame
        return scores, times.size
    if (steps < 0).any():
        order = np.argsort(times, kind="stable")
        times, scores = times[order], scores[order]
        steps = frame_steps(times)
    starts = np.flatnonzero(np.concatenate([[True], steps > 0]))
    sums = np.add.reduceat(scores, starts, axis=0)
    gaps = np.minimum(frame_steps(times[starts]), MAX_GAP_FRAMES)
    if (gaps == 1).all():
        return sums, starts.size
    slot = np.concatenate([[0], np.cumsum(gaps)])
    dense = np.zeros((int(slot[-1]) + 1, scores.shape[1]))
    dense[slot] = sums
    return dense, starts.size


def _whitener(g: NDArray) -> NDArray | None:
    """``Gamma_0^{-1/2}`` on the range of ``Gamma_0`` (None when it is zero)."""
    gamma0 = g.T @ g
    w, v = np.linalg.eigh(0.5 * (gamma0 + gamma0.T))
    keep = w > 1e-12 * max(float(w.max()), 0.0)
    if not keep.any():
        return None
    return v[:, keep] / np.sqrt(w[keep])


def _lag_trace(x: NDArray, lag: int) -> float:
    """``trace(sum_t x_t x_{t+lag}^T)``."""
    return float((x[:-lag] * x[lag:]).sum()) if lag < x.shape[0] else 0.0


def autocorrelation_factor(scores: ArrayLike, times: ArrayLike) -> float:
    """Integrated autocorrelation time ``tau >= 1`` of a score series (module doc).

    scores : (n, p) float, one score row per residual (e.g. ``A_k^T e_k``);
        rows of the same time are summed first.
    times : (n,) int, the frame (on one clock) of each row.
    Returns ``tau``: multiply a covariance that treats the frames as
    independent by it. 1.0 when the series is too short (fewer than 8
    distinct frames) or all zero.
    """
    s = np.asarray(scores, dtype=float)
    if s.ndim == 1:
        s = s[:, None]
    t = np.asarray(times, dtype=np.int64).ravel()
    if s.shape[0] != t.size or t.size == 0:
        return 1.0
    g, n_times = _frame_sums(s, t)
    if n_times < 8:
        return 1.0
    whiten = _whitener(g)
    if whiten is None:
        return 1.0
    x = g @ whiten  # Gamma_0 of x is the identity on its p' components
    p = x.shape[1]
    rho = min(max(_lag_trace(x, 1) / p, 0.0), MAX_AR_COEFFICIENT)  # np.clip's, of a float
    u = x[1:] - rho * x[:-1]
    bandwidth = int(np.ceil(4.0 * (u.shape[0] / 100.0) ** (2.0 / 9.0)))
    lrv_u = float((u * u).sum())
    for lag in range(1, bandwidth + 1):
        lrv_u += 2.0 * (1.0 - lag / (bandwidth + 1.0)) * _lag_trace(u, lag)
    tau = lrv_u / (1.0 - rho) ** 2 / p
    return float(max(tau, 1.0)) if np.isfinite(tau) else 1.0
