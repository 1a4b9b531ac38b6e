"""The Doppler sigmas of a network's nodes with the target's motion estimated jointly.

A node's own 4th differences of Doppler (:func:`~.estimate.temporal_noise`)
see the noise plus the 4th differences of the target's radial velocity. On a
smooth walk the latter are negligible, but a walker whose speed and heading
change from frame to frame (the simulator's random walk: an
Ornstein-Uhlenbeck speed, ~0.08 m/s per frame, and turns of up to 3 rad/s)
adds ~20 % to their variance, and nothing in one node's sequence separates
the two: fitted on one node alone (REML, Whittle), the walk's roughness
looks like noise at every frequency the differences keep and the noise is
left with a few dof.

Several nodes see the *same* motion: the normalised 2nd differences
``D_i = (z_i[t-1] - 2 z_i[t] + z_i[t+1]) / sqrt(6)`` of the Dopplers
``z_i = u_i . v + n_i`` are, with the lines of sight ``u_i`` nearly
constant over the three frames, ``D_i = u_i . a_t + m_i``, where ``a_t`` is
the 2nd difference of the velocity (common to all nodes) and ``m_i`` that of
node ``i``'s noise (independent of the others, variance ``sigma_i^2``).
Hence, per frame,

    E[D_i D_j] = delta_ij sigma_i^2 + u_i^T Q_t u_j,

with ``Q_t`` the covariance of ``a_t``. The walk's changes are taken along
and across its heading ``h`` (speed changes and turns):
``Q_t = q_par h h^T + q_perp h_perp h_perp^T``, so the products of the
nodes' differences are linear in ``N + 2`` unknowns, fitted by generalised
least squares over the frames (per frame the products' Gaussian covariance
``Cov(D_a D_b, D_c D_d) = S_ac S_bd + S_ad S_bc`` at the current fit,
iterated). The cross products ``D_i D_j`` see only the motion, so they fix
``q_par, q_perp`` wherever two lines of sight are not perpendicular, and the
squares then give each ``sigma_i^2`` with the motion taken out. Nothing is
assumed about how rough the motion is (random walk, integrated random walk,
sudden turns: whatever its 2nd differences' covariance, as long as it is
aligned with the heading); what is assumed is that the nodes' noises are
independent. The lines of sight and the heading come from each frame's
least-squares state at the given poses. The variances' covariance is that of
the GLS fit (frames independent) times :func:`difference_kappa` (consecutive
differences are correlated); ``dof = 2 sigma^4 / var(sigma^2)``: the motion
costs precision, most for the quieter node (its ``sigma^2`` is the
difference of two larger variances); perpendicular lines of sight leave the
noise and the motion unseparated, and the dof say so.

2nd differences (3 consecutive frames) rather than the 4th of
:func:`~.estimate.temporal_noise`: the motion is fitted, not
differenced away, and the 2nd differences are less correlated (1.94 against
2.63) and survive gaps and ghosts better. Differences beyond
:data:`MOTION_GATE_K` robust sigmas are trimmed (the truncation corrected).
Bias and precision (tests/calibration/noise/test_motion.py):
docs/validation/calibration.md, "Figures behind the estimators' rules".
"""

from __future__ import annotations

import math
from typing import Mapping

import numpy as np
from numpy.typing import NDArray

from ..._validation import check_count
from ...data.recording import Detections
from ...errors import ValidationError

__all__ = ["motion_doppler_noise", "difference_kappa", "MOTION_GATE_K", "MOTION_ORDER"]

#: Differences beyond this many robust sigmas are left out (ghosts that the
#: screening missed; the truncation of Gaussian differences at 4 sigmas
#: biases the variance by < 0.2 %).
MOTION_GATE_K = 3.0
#: Order of the differences (2: three consecutive frames per difference).
MOTION_ORDER = 2


def _trim_factor(k: float) -> float:
    """``E[e^2 | |e| < k sigma] / sigma^2`` for a normal ``e``."""
    pdf = math.exp(-0.5 * k * k) / math.sqrt(2.0 * math.pi)
    return 1.0 - 2.0 * k * pdf / math.erf(k / math.sqrt(2.0))


def _weights(order: int) -> NDArray:
    c = np.array([(-1.0) ** (order - j) * math.comb(order, j) for j in range(order + 1)])
    return c / np.sqrt(np.sum(c**2))


def difference_kappa(order: int) -> float:
    """Variance of a mean of squares (or products) of consecutive normalised
    ``order``-th differences of white noise relative to independent ones:
    ``1 + 2 sum_m rho_m^2`` (``rho_m`` their autocorrelations); 1.94 for
    order 2, 2.63 for order 4."""
    w = _weights(order)
    rho = np.correlate(w, w, "full")[order + 1:]
    return float(1.0 + 2.0 * np.sum(rho**2))


def _doppler_table(detections: Mapping[str, Detections], names) -> tuple[NDArray, NDArray]:
    """The frames ``(T,)`` any node has a centroid in, sorted, and each
    node's Doppler ``(T, N)`` there (NaN where it has none, or several)."""
    frames = np.unique(np.concatenate([detections[n].frame for n in names]))
    z = np.full((frames.size, len(names)), np.nan)
    for j, n in enumerate(names):
        det = detections[n]
        f, counts = np.unique(det.frame, return_counts=True)
        single = np.isin(det.frame, f[counts == 1])
        z[np.searchsorted(frames, det.frame[single]), j] = det.doppler_mps[single]
    return frames, z


def _differences(frames: NDArray, z: NDArray, k: float, order: int) -> NDArray:
    """Centred normalised ``order``-th differences ``(T, N)`` over
    ``order + 1`` consecutive frames (NaN where there are none), trimmed at
    ``k`` robust sigmas per node and rescaled for the truncation."""
    w = _weights(order)
    d = np.full_like(z, np.nan)
    if frames.size <= order:
        return d
    win = np.lib.stride_tricks.sliding_window_view(z, order + 1, axis=0)    # (T - order, N, o+1)
    run = (frames[order:] - frames[:-order]) == order                         # consecutive frames
    d[order // 2: order // 2 + win.shape[0]] = np.where(run[:, None], win @ w, np.nan)
    for j in range(d.shape[1]):
        col = d[:, j]
        ok = np.isfinite(col)
        if not np.any(ok):
            continue
        s = 1.4826 * float(np.median(np.abs(col[ok])))
        for _ in range(4):      # from the median, the trimmed scale (truncation corrected)
            keep = ok & (np.abs(col) <= k * max(s, 1e-12))
            s = float(np.sqrt(np.mean(col[keep] ** 2) / _trim_factor(k)))
        col[ok & (np.abs(col) > k * max(s, 1e-12))] = np.nan
    return d / np.sqrt(_trim_factor(k))


def _design(d: NDArray, states: NDArray, poses: NDArray) -> tuple[NDArray, NDArray, NDArray, NDArray]:
    """Per frame and node pair ``(a <= b)``: products ``y (F, P)``, design
    ``X (F, P, N + 2)``, validity ``ok (F, P)`` and the pairs ``(P, 2)``."""
    f, n = d.shape
    los = states[:, None, :2] - poses[None, :, :2]
    los /= np.linalg.norm(los, axis=-1, keepdims=True)                  # (F, N, 2)
    speed = np.linalg.norm(states[:, 2:], axis=-1, keepdims=True)
    head = states[:, 2:] / np.maximum(speed, 1e-9)
    perp = np.stack([-head[:, 1], head[:, 0]], -1)
    up = np.einsum("fnc,fc->fn", los, head)
    uq = np.einsum("fnc,fc->fn", los, perp)
    pairs = np.array([(a, b) for a in range(n) for b in range(a, n)])
    ia, ib = pairs[:, 0], pairs[:, 1]
    x = np.zeros((f, pairs.shape[0], n + 2))
    diag = np.nonzero(ia == ib)[0]
    x[:, diag, ia[diag]] = 1.0
    x[..., n] = up[:, ia] * up[:, ib]
    x[..., n + 1] = uq[:, ia] * uq[:, ib]
    ok = np.isfinite(d[:, ia]) & np.isfinite(d[:, ib])
    y = np.where(ok, np.nan_to_num(d[:, ia]) * np.nan_to_num(d[:, ib]), 0.0)
    return y, x, ok, pairs


def _normal_equations(y, x, ok, pairs, theta) -> tuple[NDArray, NDArray]:
    """``X^T W X`` and ``X^T W y`` of a block of frames, ``W`` the inverse of
    the products' Gaussian covariance at ``theta`` (module doc)."""
    f, p, m = x.shape
    n = m - 2
    ia, ib = pairs[:, 0], pairs[:, 1]
    fit = np.zeros((f, n, n))
    fit[:, ia, ib] = np.einsum("fpm,m->fp", x, theta)        # fitted E[D_a D_b]
    fit[:, ib, ia] = fit[:, ia, ib]
    # cov[f, r, c] = S[a_r, a_c] S[b_r, b_c] + S[a_r, b_c] S[b_r, a_c]
    cov = (fit[:, ia[:, None], ia[None, :]] * fit[:, ib[:, None], ib[None, :]]
           + fit[:, ia[:, None], ib[None, :]] * fit[:, ib[:, None], ia[None, :]])
    mask = ok[:, :, None] & ok[:, None, :]
    wgt = np.where(mask, np.linalg.inv(np.where(mask, cov, np.eye(p))), 0.0)
    wx = (wgt @ x).reshape(-1, m)                             # W X, frames stacked
    return x.reshape(-1, m).T @ wx, wx.T @ y.ravel()


#: Elements of one (frames, pairs, pairs) array of a block of
#: :func:`_normal_equations` (8 MB of float64): the block's frames follow
#: from the node pairs. A fixed 4096 frames held 10 nodes' 55 pairs in
#: arrays of 99 MB, several at once: 530 MB above the calibration's peak.
_BLOCK_ELEMENTS = 1 << 20


def _gls(y, x, ok, pairs, theta, n_rounds: int = 4,
         chunk: int | None = None) -> tuple[NDArray, NDArray]:
    """Generalised least squares of the products on the design, the weights
    at the current fit, ``n_rounds`` times; returns the fit and its
    covariance (frames independent). ``chunk``: frames per block (None:
    :data:`_BLOCK_ELEMENTS` over the pairs squared)."""
    m = x.shape[-1]
    n = m - 2
    if chunk is None:
        chunk = max(_BLOCK_ELEMENTS // max(pairs.shape[0], 1) ** 2, 16)
    x = np.where(ok[..., None], x, 0.0)
    info = np.eye(m)
    for _ in range(n_rounds):
        info, rhs = np.zeros((m, m)), np.zeros(m)
        for s in range(0, y.shape[0], chunk):
            i, r = _normal_equations(y[s:s + chunk], x[s:s + chunk], ok[s:s + chunk], pairs,
                                     theta)
            info += i
            rhs += r
        info += 1e-12 * np.trace(info) * np.eye(m)
        theta = np.linalg.solve(info, rhs)
        theta[:n] = np.maximum(theta[:n], 1e-6 * np.max(theta[:n]))
        theta[n:] = np.maximum(theta[n:], 0.0)
    return theta, np.linalg.inv(info)


def _validated(names, poses, states, state_frames, initial, order):
    if len(names) < 2:
        raise ValidationError(f"motion_doppler_noise needs at least two nodes, got {names!r}")
    missing = [n for n in names if n not in poses]
    if missing:
        raise ValidationError(f"motion_doppler_noise: no pose for nodes {missing}")
    states = np.asarray(states, dtype=float)
    state_frames = np.asarray(state_frames)
    if states.ndim != 2 or states.shape[1] != 4 or state_frames.shape != states.shape[:1]:
        raise ValidationError(f"states must have shape (F, 4) and state_frames (F,), got "
                              f"{states.shape} and {state_frames.shape}")
    if state_frames.size > 1 and np.any(np.diff(state_frames) <= 0):
        raise ValidationError("state_frames must be strictly increasing")
    initial = np.asarray(initial, dtype=float)
    if initial.shape != (len(names),) or not np.all(np.isfinite(initial) & (initial > 0)):
        raise ValidationError(f"initial must be {len(names)} finite sigmas > 0, got {initial!r}")
    check_count(order, "order", 1, 6)
    return states, state_frames, initial


def motion_doppler_noise(detections: Mapping[str, Detections], poses: Mapping[str, NDArray],
                         states: NDArray, state_frames: NDArray, *,
                         initial: NDArray, k: float = MOTION_GATE_K,
                         order: int = MOTION_ORDER) -> tuple[NDArray, NDArray, NDArray]:
    """Each node's Doppler sigma with the target's motion fitted jointly
    (module doc).

    detections : name -> one node's centroids (frames on a common clock,
        ghosts already removed).
    poses : name -> (3,) node pose. states, state_frames : each frame's
        least-squares target state ``(F, 4)`` and its frame number ``(F,)``.
    initial : (N,) starting Doppler sigmas (weights of the first round).
    k : trimming threshold (robust sigmas) of each node's differences.
    order : order of the differences.
    Returns ``(sigmas (N,), dof (N,), counts (N,))``: NaN / 0 where no
    difference is usable.
    """
    names = list(detections)
    states, state_frames, initial = _validated(names, poses, states, state_frames, initial,
                                               order)
    n = len(names)
    frames, z = _doppler_table(detections, names)
    d = _differences(frames, z, k, order)
    at = np.searchsorted(state_frames, frames)
    has = (at < state_frames.size) & (state_frames[np.minimum(at, state_frames.size - 1)]
                                         == frames)
    d, st = d[has], states[at[has]]
    good = np.all(np.isfinite(st), axis=1) & (np.linalg.norm(st[:, 2:], axis=1) > 1e-3)
    d, st = d[good], st[good]
    counts = np.sum(np.isfinite(d), axis=0).astype(np.int64)
    if d.shape[0] == 0 or np.count_nonzero(counts) < 2:
        return np.full(n, np.nan), np.zeros(n), counts
    p = np.array([np.asarray(poses[nm], dtype=float) for nm in names])
    y, x, ok, pairs = _design(d, st, p)
    theta0 = np.concatenate([initial**2, [0.0, 0.0]])
    theta, cov = _gls(y, x, ok, pairs, theta0)
    var = np.diag(cov)[:n] * difference_kappa(order)
    # A negative variance estimate is not identified (NaN), without numpy's
    # "invalid value in sqrt" warning reaching the user.
    sig = np.full(n, np.nan)
    usable = (counts > 0) & (theta[:n] >= 0)
    sig[usable] = np.sqrt(theta[:n][usable])
    dof = np.where((counts > 0) & (var > 0), 2.0 * theta[:n] ** 2 / np.maximum(var, 1e-300), 0.0)
    return sig, dof, counts
