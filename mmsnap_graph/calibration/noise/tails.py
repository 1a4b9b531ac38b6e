"""The second moment of heavy-tailed centroid noise (docs/CONVENTIONS.md).

A Gaussian covariance is honest in the mean (mean NEES = dimension) when the
sigmas it is built from are the root mean square of the errors it fuses. The
robust estimators of :mod:`mmsnap_graph.calibration.noise.estimate` give the
scale of the *core* of the errors: they screen ghosts and trim beyond a few
robust sigmas. On Gaussian centroids the two agree. Centroids made by the
radar chain from point clouds (the torso cluster of a walking body, limbs
leaking in) are heavy-tailed: a few per cent of their errors, beyond 5
robust sigmas, carry a large part of the second moment, the robust sigmas
fall short of the root mean square and the fused NEES comes out about twice
its dimension (the figures: docs/validation/calibration.md, "Figures behind the estimators' rules").

The tails are not ghosts: they pass the association's gate, the fusion uses
them, so the covariance must count them. :func:`tail_variances` measures, per
node and component, the excess of the mean square of each node's own 4th
differences over their trimmed scale squared (a slow trend, such as a random
walk's Doppler, is in both and cancels), over the centroids the fusion would
fuse: the frames whose centroids (one per node, two nodes or more) pass a
chi-square consistency test at :data:`TAIL_GATE_PROBABILITY` (a gross-error
gate: a ghost fails it by far and leaves, as the fusion's gates take it out
of a fused frame; a tail passes it, as it passes into the fused output), less
the rows whose difference window is gross (:data:`TAIL_GROSS_K`). An excess
counts only when it is significant (:data:`TAIL_Z` null standard
deviations): Gaussian centroids keep their sigmas. :func:`with_tails` adds
these excess variances to a :class:`NoiseEstimate`'s identified variances
(two rounds: wider sigmas let more frames pass the gate). It needs the node
poses of two nodes or more; without them the estimate is returned unchanged.

Sparse clouds (a node missing the person in one frame of five or six, as
the simulator's real model and the TI recordings do) leave few runs of five
consecutive frames, far fewer than :data:`TAIL_MIN_DIFFERENCES`, so the
4th differences count no tail and the Doppler sigma stays at the core's.
There the excess comes from leave-one-out residuals instead
(:func:`_loo_residuals`: each row against a quadratic in time through its
neighbours within :data:`TAIL_LOO_REACH` frames, gaps allowed), whose fits
leave out gross rows, rows that cannot be tested and rows beyond
:data:`TAIL_FIT_K` core scales; rows beyond :data:`TAIL_LOO_GROSS_K` are
gross. Gaussian sparse centroids keep their sigmas; contaminated ones move
toward the root mean square (the fits hold fewer tails than the rows
tested).

Limits (tests/calibration/noise/test_tails.py): the 4th differences mix five
centroids, which makes rare wide errors look more Gaussian, so the excess is
an underestimate. Two facing nodes cannot check each other's Doppler, so a
ghost Doppler within :data:`TAIL_GROSS_K` passes for a tail (as the fusion
fuses it). The figures: docs/validation/calibration.md, "Figures behind the estimators' rules".
"""

from __future__ import annotations

import math
from typing import Mapping

import numpy as np
from numpy.typing import NDArray

from ..._validation import chi2_gate
from ...data.noise import MeasurementNoise, NodeNoiseEstimate, NoiseEstimate
from ...data.recording import Detections
from .frame_states import solve_frame_states
from .sequences import ghost_rows

__all__ = ["TAIL_GATE_PROBABILITY", "TAIL_Z", "TAIL_ORDER", "TAIL_GROSS_K",
           "TAIL_MIN_DIFFERENCES", "consistent_rows",
           "tail_variances", "with_tails"]

#: Gate of the frame consistency test: a gross-error gate, far beyond what
#: genuine heavy-tailed centroids reach and far below ghosts' frames, so
#: that it keeps every tail the fusion keeps and no ghost. (This module's
#: constants were set by simulation of Gaussian, contaminated and ghost
#: centroids; tests/calibration/noise/test_tails.py checks the outcomes.)
TAIL_GATE_PROBABILITY = 1.0 - 1e-12
#: Null standard deviations by which the excess must exceed 0 to count
#: (above what Gaussian centroids of a random walk reach through the walk's
#: own uneven 4th differences).
TAIL_Z = 4.0
#: Difference windows beyond this many trimmed scales are gross (a ghost the
#: frame gate let through); the chain's tails reach about 12.
TAIL_GROSS_K = 20.0
#: Fewest differences for a component's test (on far fewer than the null
#: spread was measured on, Gaussian nodes exceed :data:`TAIL_Z`).
TAIL_MIN_DIFFERENCES = 200
#: Order of the differences (as the temporal estimator).
TAIL_ORDER = 4
#: Trimming (robust sigmas) of the core scale the excess is taken against.
_TRIM_K = 3.0
_ROUNDS = 2
#: Variance of the mean square of 4th differences of white noise relative to
#: independent residuals (as :data:`.estimate.KAPPA_4`).
_KAPPA_4 = 1.0 + 2.0 * ((56 / 70) ** 2 + (28 / 70) ** 2 + (8 / 70) ** 2 + (1 / 70) ** 2)
#: Standard deviation of ``mean(e^2) - s^2`` (``s`` the trimmed scale) on
#: Gaussian 4th differences, in units of ``s^2 sqrt(2 KAPPA_4 / n)``
#: (measured by simulation).
_NULL_SPREAD = 0.30
#: Reach (frames on either side) of the leave-one-out fits of :func:`_loo_residuals`.
TAIL_LOO_REACH = 3
#: Gross residuals of the leave-one-out path, in trimmed scales: a ghost
#: shows nearly whole in its own residual (not mixed with four neighbours as
#: in a difference), beyond this; the real model's rarest centroid Doppler
#: errors reach it too and are cut as gross.
TAIL_LOO_GROSS_K = 12.0
_LOO_SCREEN_ROUNDS = 3
#: Fewest fit rows of a leave-one-out residual (three fix the quadratic).
_LOO_MIN_FIT = 3
#: Rows beyond this many core scales of their own leave-one-out fit leave
#: the fits of their neighbours (they are still tested themselves).
TAIL_FIT_K = 8.0
#: Standard deviation of ``mean(r^2) - s^2`` on Gaussian leave-one-out
#: residuals, in units of ``s^2 / sqrt(n)`` (measured by simulation on
#: sequences with 30 % of the frames missed).
_LOO_NULL_SPREAD = 0.66


def _single_rows(det: Detections) -> NDArray:
    frames, counts = np.unique(det.frame, return_counts=True)
    return np.isin(det.frame, frames[counts == 1])


def _frame_table(dets: Mapping[str, Detections], names) -> tuple[NDArray, NDArray]:
    """Frames seen with exactly one centroid by at least two nodes, and the
    measurements ``(F, N, 3)`` (NaN = not seen)."""
    single = {n: dets[n].frame[_single_rows(dets[n])] for n in names}
    frames, counts = np.unique(np.concatenate([single[n] for n in names]), return_counts=True)
    frames = frames[counts >= 2]
    z = np.full((frames.size, len(names), 3), np.nan)
    for j, n in enumerate(names):
        rows = _single_rows(dets[n]) & np.isin(dets[n].frame, frames)
        z[np.searchsorted(frames, dets[n].frame[rows]), j] = dets[n].measurements[rows]
    return frames, z


def _frame_chi2(z: NDArray, poses: NDArray, sig: NDArray, iterations: int = 8) -> NDArray:
    """Per frame, the weighted least-squares residual chi-square of the
    nodes that see it (Gauss-Newton from the first node's detection; a weak
    prior keeps an unobserved velocity direction in place)."""
    w = np.where(np.isfinite(z[..., :1]), 1.0 / sig[None] ** 2, 0.0)
    x, e = solve_frame_states(z, poses, w, np.full(4, 1e-6), iterations)[:2]
    chi2 = np.nansum(w * e**2, axis=(1, 2))
    return np.where(np.isfinite(x[:, 0]), chi2, np.nan)  # an unsolved frame is not consistent


def consistent_rows(detections: Mapping[str, Detections], poses: Mapping[str, NDArray],
                    noise: Mapping[str, MeasurementNoise], *,
                    gate_probability: float = TAIL_GATE_PROBABILITY) -> dict[str, NDArray]:
    """name -> (K,) bool: the node's centroids in frames whose centroids (one
    per node, two nodes or more) pass the chi-square consistency test of
    their joint least-squares fit at ``noise`` (``3 n - 4`` dof)."""
    names = [n for n in detections if n in poses and n in noise]
    out = {n: np.zeros(len(d), bool) for n, d in detections.items()}
    if len(names) < 2:
        return out
    frames, z = _frame_table(detections, names)
    if frames.size == 0:
        return out
    p = np.array([np.asarray(poses[n], dtype=float) for n in names])
    sig = np.array([noise[n].sigmas for n in names])
    stat = _frame_chi2(z, p, sig)
    dof = 3 * np.sum(np.isfinite(z[..., 0]), axis=1) - 4
    ok = stat <= chi2_gate(gate_probability, np.maximum(dof, 1))
    for j, n in enumerate(names):
        good = frames[ok & np.isfinite(z[:, j, 0])]
        out[n] = _single_rows(detections[n]) & np.isin(detections[n].frame, good)
    return out


def _differences(det: Detections, rows: NDArray, order: int) -> NDArray:
    """Normalised ``order``-th differences ``(M, 3)`` on runs of consecutive
    frames of the selected rows (omega unwrapped)."""
    c = np.array([(-1) ** (order - j) * math.comb(order, j) for j in range(order + 1)], float)
    c /= np.sqrt(np.sum(c**2))
    idx = np.flatnonzero(rows)
    idx = idx[np.argsort(det.frame[idx], kind="stable")]
    parts = []
    for run in np.split(idx, np.nonzero(np.diff(det.frame[idx]) != 1)[0] + 1):
        if run.size <= order:
            continue
        z = det.measurements[run]
        z[:, 1] = np.unwrap(z[:, 1])
        parts.append(np.lib.stride_tricks.sliding_window_view(z, order + 1, axis=0) @ c)
    return np.concatenate(parts) if parts else np.zeros((0, 3))


def _loo_residuals(det: Detections, test: NDArray, fit: NDArray,
                   reach: int = TAIL_LOO_REACH) -> tuple[NDArray, NDArray, NDArray]:
    """Leave-one-out residuals ``(M, 3)`` of the ``test`` rows (omega
    unwrapped): each row against the quadratic in time fitted to the other
    ``fit`` rows within ``reach`` frames (at least :data:`_LOO_MIN_FIT`, one on either
    side). Unlike the differences of :func:`_differences` they need no run
    of consecutive frames: sparse clouds (a node missing the person in one
    frame of five) leave few runs of five. Returns the residuals, each
    fit's variance at its row over the noise's (``h``) and the rows'
    indices."""
    none = np.zeros((0, 3)), np.zeros(0), np.zeros(0, np.int64)
    idx = np.flatnonzero(fit | test)
    idx = idx[np.argsort(det.frame[idx], kind="stable")]
    if idx.size < 4:
        return none
    f = det.frame[idx].astype(float)
    z = det.measurements[idx]
    z[:, 1] = np.unwrap(z[:, 1])
    use = fit[idx]
    a = np.flatnonzero(test[idx])
    if a.size == 0:
        return none
    # Every tested row's window at once: (M, W) candidate neighbours, the
    # rows within ``reach`` frames but the row itself, of the fit rows.
    lo = np.searchsorted(f, f[a] - reach)
    hi = np.searchsorted(f, f[a] + reach, side="right")
    nb = lo[:, None] + np.arange(int(np.max(hi - lo)))
    ok = (nb < hi[:, None]) & (nb != a[:, None])
    nb = np.minimum(nb, idx.size - 1)
    ok &= use[nb]
    t = np.where(ok, f[nb] - f[a][:, None], 0.0)
    keep = ((np.count_nonzero(ok, axis=1) >= _LOO_MIN_FIT)
            & np.any(t < 0, axis=1) & np.any(t > 0, axis=1))
    if not keep.any():
        return none
    a, nb, ok, t = a[keep], nb[keep], ok[keep], t[keep]
    # The quadratic's design rows (1, t, t^2), zero for the rows not in a fit.
    x = np.stack([ok, t, t * t], axis=-1).astype(float)
    g = np.linalg.pinv(np.einsum("mwi,mwj->mij", x, x))
    coef0 = np.einsum("mj,mwj,mwc->mc", g[:, 0, :], x, z[nb])  # the fit's value at t = 0
    return z[a] - coef0, g[:, 0, 0], idx[a]


def _loo_moments(det: Detections, rows: NDArray, gross_k: float
                 ) -> tuple[NDArray, NDArray, NDArray]:
    """Per component, the core scale ``s``, the second moment and the count
    of the selected ``rows``' errors from :func:`_loo_residuals`.

    The fits use the node's single-centroid rows (the consistent ones are
    too sparse where the other nodes miss frames too) less the gross ones
    (beyond ``gross_k`` robust scales of the median of their neighbours'
    predictions, :func:`~mmsnap_graph.calibration.noise.sequences.ghost_rows`)
    and those that cannot be tested themselves (no neighbours on a side),
    then, round by round, those beyond :data:`TAIL_FIT_K` core scales of
    their own fit: a tail or a ghost left in a fit would show again in its
    neighbours' residuals. Each residual is divided by ``sqrt(1 + h)`` (``h``
    its fit's variance over the noise's): the mean square is then the second
    moment of Gaussian errors, and on heavy tails a little short of it (the
    fits hold fewer tails than the rows tested). Tested rows beyond
    ``gross_k`` core scales are gross and left out."""
    clean = _single_rows(det) & ~ghost_rows(det, k=gross_k)
    fit = clean
    for k in range(_LOO_SCREEN_ROUNDS):
        r, h, at = _loo_residuals(det, fit, fit)
        if r.shape[0] == 0:
            break
        zs = r / np.sqrt(1.0 + h)[:, None]
        scale = np.array([_trimmed_scale(zs[:, c]) for c in range(3)])
        out = at[np.any(np.abs(zs) > TAIL_FIT_K * np.maximum(scale, 1e-300), axis=1)]
        if k == 0:        # a row that cannot be tested (no neighbours on a side) leaves once
            fit = np.zeros_like(fit)
            fit[at] = True
        elif out.size == 0:
            break
        fit = fit.copy()
        fit[out] = False
    r, h, _ = _loo_residuals(det, rows & clean, fit)
    s, m2, n = np.zeros(3), np.zeros(3), np.zeros(3, np.int64)
    for c in range(3):
        if r.shape[0] == 0:
            break
        zc = r[:, c] / np.sqrt(1.0 + h)
        s[c] = _trimmed_scale(zc)
        ok = np.abs(zc) <= gross_k * s[c]
        m2[c] = float(np.mean(zc[ok] ** 2)) if np.any(ok) else 0.0
        n[c] = int(np.count_nonzero(ok))
    return s, m2, n


def _trimmed_scale(e: NDArray, k: float = _TRIM_K) -> float:
    """Scale of the core of ``e``: a median start, trimming at ``k`` scales
    with the normal truncation corrected (consistent on Gaussian ``e``)."""
    pdf = math.exp(-0.5 * k * k) / math.sqrt(2.0 * math.pi)
    factor = 1.0 - 2.0 * k * pdf / math.erf(k / math.sqrt(2.0))
    s = 1.4826 * float(np.median(np.abs(e)))
    for _ in range(6):
        if not s > 0:
            break
        keep = np.abs(e) <= k * s
        s = float(np.sqrt(np.mean(e[keep] ** 2) / factor))
    return s


def _gross_rows(det: Detections, rows: NDArray, order: int, gross_k: float) -> NDArray:
    """The selected rows that sit at the centre of a difference window
    within ``gross_k`` trimmed scales in every component (a ghost that
    slipped through the frame gate fails: the centre weight of a 4th
    difference is 0.72). The first and last ``order / 2`` rows of a run are
    never a centre, so never tested, and leave too."""
    c = np.array([(-1) ** (order - j) * math.comb(order, j) for j in range(order + 1)], float)
    c /= np.sqrt(np.sum(c**2))
    idx = np.flatnonzero(rows)
    idx = idx[np.argsort(det.frame[idx], kind="stable")]
    runs = [r for r in np.split(idx, np.nonzero(np.diff(det.frame[idx]) != 1)[0] + 1)
            if r.size > order]
    if not runs:
        return rows
    d = np.concatenate([np.lib.stride_tricks.sliding_window_view(
        np.column_stack([det.measurements[r][:, 0], np.unwrap(det.measurements[r][:, 1]),
                         det.measurements[r][:, 2]]), order + 1, axis=0) @ c for r in runs])
    centre = np.concatenate([r[order // 2: r.size - order + order // 2] for r in runs])
    scale = np.array([_trimmed_scale(d[:, k]) for k in range(3)])
    bad = np.any(np.abs(d) > gross_k * np.maximum(scale, 1e-300), axis=1)
    out = np.zeros_like(rows)
    out[centre[~bad]] = True      # only rows tested at a window's centre
    return out


def tail_variances(detections: Mapping[str, Detections], rows: Mapping[str, NDArray], *,
                   order: int = TAIL_ORDER, z: float = TAIL_Z,
                   gross_k: float = TAIL_GROSS_K) -> dict[str, NDArray]:
    """name -> (3,) excess variance ``>= 0`` per component: the mean square
    of the node's ``order``-th differences over ``rows`` (less the gross
    ones, beyond ``gross_k`` trimmed scales) minus their trimmed scale
    squared, where that excess is significant (``z`` standard deviations of
    its Gaussian null, :data:`_NULL_SPREAD`, on at least
    :data:`TAIL_MIN_DIFFERENCES` differences); 0 elsewhere. A slow trend in
    the differences (a random walk's Doppler) is in both terms and cancels."""
    out = {}
    for n, det in detections.items():
        keep = rows.get(n, np.zeros(len(det), bool))
        d = _differences(det, _gross_rows(det, keep, order, gross_k), order)
        if d.shape[0] < TAIL_MIN_DIFFERENCES:      # short runs: leave-one-out residuals
            out[n] = _loo_excess(det, keep, min(gross_k, TAIL_LOO_GROSS_K), z)
            continue
        v = np.zeros(3)
        for c in range(3):
            e = d[:, c]
            s = _trimmed_scale(e)
            if not s > 0:
                continue
            excess = float(np.mean(e**2)) - s * s
            if excess > z * _NULL_SPREAD * s * s * math.sqrt(2.0 * _KAPPA_4 / e.size):
                v[c] = excess
        out[n] = v
    return out


def _loo_excess(det: Detections, rows: NDArray, gross_k: float, z: float) -> NDArray:
    """(3,) excess of the second moment over the core's variance from
    :func:`_loo_moments`, where significant (``z`` null standard
    deviations, :data:`_LOO_NULL_SPREAD`, on at least
    :data:`TAIL_MIN_DIFFERENCES` rows); 0 elsewhere."""
    s, m2, n = _loo_moments(det, rows, gross_k)
    v = np.zeros(3)
    for c in range(3):
        if n[c] < TAIL_MIN_DIFFERENCES or not s[c] > 0:
            continue
        excess = m2[c] - s[c] ** 2
        if excess > z * _LOO_NULL_SPREAD * s[c] ** 2 / math.sqrt(n[c]):
            v[c] = excess
    return v


def _scaled(est: NodeNoiseEstimate, excess: NDArray) -> NodeNoiseEstimate:
    v = np.where(est.identified, excess, 0.0)
    if np.all(v == 0.0):
        return est
    s = np.sqrt(est.noise.sigmas**2 + v)
    return NodeNoiseEstimate(
        noise=MeasurementNoise(range_m=s[0], omega_rad=s[1], doppler_mps=s[2]),
        identified=est.identified, n_residuals=est.n_residuals, method=est.method,
        reasons=est.reasons, tail_factors=tuple(np.maximum(s / est.noise.sigmas, 1.0)))


def with_tails(estimate: NoiseEstimate, detections: Mapping[str, Detections],
               poses: Mapping[str, NDArray] | None) -> NoiseEstimate:
    """``estimate`` with each node's identified sigmas scaled by its
    :func:`tail_variances` over its :func:`consistent_rows` (module doc);
    unchanged without poses for two nodes or where no tail is significant.

    detections : name -> one node's centroids on a common clock (lags removed).
    poses : name -> (3,) node pose, or None.
    """
    if poses is not None:
        poses = {n: p for n, p in poses.items() if p is not None}
    if poses is None or sum(n in poses for n in detections) < 2:
        return estimate
    nodes = dict(estimate.nodes)
    for _ in range(_ROUNDS):
        rows = consistent_rows(detections, poses, {n: e.noise for n, e in nodes.items()})
        excess = tail_variances(detections, rows)
        nodes = {n: (_scaled(e, excess[n]) if n in excess else e)
                 for n, e in estimate.nodes.items()}
    scaled = [n for n in nodes if nodes[n] is not estimate.nodes[n]]
    msg = estimate.message + (f"; heavy tails counted (second moment) for {', '.join(scaled)}"
                              if scaled else "")
    return NoiseEstimate(nodes=nodes, fallback=estimate.fallback, method=estimate.method,
                         message=msg)
