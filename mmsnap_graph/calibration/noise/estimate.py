"""Each node's measurement noise from a recording's own data.

:func:`estimate_noise` gives every node's range, spatial-frequency and
Doppler sigmas (a :class:`~mmsnap_graph.data.noise.NoiseEstimate`) from two
estimators of the same variances, both quadratic forms of the centroids'
noise with their expectation corrected to the noise variance:

- **network** (:func:`network_noise`, needs the node poses): the residuals
  of each frame's weighted least-squares state (one target seen by several
  nodes at known poses), one variance per node and component estimated by
  REML (Fisher scoring on the per-frame residuals, whose covariance is
  ``R = W - W J C J^T W``; the simple form ``sigma^2 = sum e^2 / sum (1 - h)``
  with the leverage ``h`` is its diagonal approximation). It assumes nothing
  about the motion (each frame stands alone), so a turning or stopping target
  does not bias it; but it only sees what other nodes check, and its
  information matrix says how much: the Doppler of two nodes fixes each
  frame's velocity (no residual: 0 dof), and two nodes that measure one
  coordinate alike (range against range on facing nodes) check only the sum
  of their variances (the split has few dof). The per-node Doppler of three
  nodes has one check per frame for three variances: a few dof only.
- **temporal** (:func:`temporal_noise`, no poses, any number of nodes): the
  normalised 4th-order differences of each node's own sequence of centroids
  on runs of consecutive frames. They cancel any cubic trend in 5 frames
  (0.6 s at 150 ms), so what remains is the noise plus the trend's 4th
  difference, negligible for a walking torso's range and angle. A target
  whose velocity is rough (the simulator's random walk has an
  Ornstein-Uhlenbeck speed) passes part of it for Doppler noise. The
  differences of white noise are correlated (the variance of the estimate is
  ``KAPPA_4 = 2.63`` times that of independent residuals).

- **motion** (:func:`~.motion.motion_doppler_noise`, with poses, the
  Doppler only): the same target's motion is common to all nodes, the noise
  is not: the products of the nodes' 2nd differences of Doppler give each
  node's variance with the walk's along- and across-heading roughness fitted
  jointly. With poses it replaces the temporal Doppler estimate (unbiased on
  the random walk; ~120-230 dof per node on 600 frames instead of ~230, the
  price of fitting the motion, and it says so in its dof).

The network's likelihood and the temporal (and motion) estimates (taken as
independent observations of each variance with ``KAPPA_4 / n`` relative
variance, or ``2 / dof`` for the motion's) are maximised together, so the temporal estimates resolve what the network
cannot split, and each component's degrees of freedom ``dof = 2 sigma^4 /
var(sigma^2)`` come from the combined information (relative standard error
of a sigma about ``1 / sqrt(2 dof)``). Ghosts are left out: centroids far from the running
median of their own sequence first (:func:`ghost_rows`, for both
estimators), then differences beyond :data:`TRIM_K` robust sigmas (the
truncation corrected) and cross-node residuals beyond :data:`NETWORK_GATE_K`
standard deviations. A component with fewer than ``min_dof`` (:data:`MIN_DOF`) dof is
**not identified**: the fallback's value (the paper's by default) is used and
the reason is recorded. Temporal noise correlation (which the differences
do not see) is not modelled.

Pooling (``pool=True``): when the nodes' estimates of a component agree
within their standard errors (chi-square test of homogeneity of the log
sigmas, 2 dof per unit of ``log sigma`` variance, at :data:`POOL_LEVEL`),
every identified node gets the dof-weighted pooled value: a network of one
radar model then shares its sigma (about ``sqrt(N)`` times more precise);
nodes that differ keep their own.

The estimators' bias and precision on the simulator's networks:
docs/CALIBRATION.md, "Noise from the data".
"""

from __future__ import annotations

import math
from typing import Literal, Mapping

import numpy as np
from numpy.typing import NDArray

from ..._validation import chi2_gate
from ...data.noise import MeasurementNoise, NodeNoiseEstimate, NoiseEstimate
from ...data.recording import Detections, Recording
from ...errors import ValidationError
from .frame_states import frame_table as _frame_table, solve_frame_states, without_unsolved
from .motion import motion_doppler_noise
from .sequences import GHOST_K, ghost_rows
from .sequences import single_target_sequences as _sequences
from .tails import with_tails

__all__ = ["estimate_noise", "network_noise", "temporal_noise", "TEMPORAL_ORDER", "KAPPA_4",
           "MIN_DOF", "TRIM_K", "NETWORK_GATE_K", "POOL_LEVEL", "GHOST_K",
           "trimmed_scale", "ghost_rows"]

#: Order of the differences of :func:`temporal_noise`.
TEMPORAL_ORDER = 4
#: Variance of the mean square of 4th differences of white noise relative to
#: independent residuals: ``1 + 2 sum_m rho_m^2`` (rho = -0.8, 0.4, -4/35, 1/70).
KAPPA_4 = 1.0 + 2.0 * ((56 / 70) ** 2 + (28 / 70) ** 2 + (8 / 70) ** 2 + (1 / 70) ** 2)
#: Cross-node residuals beyond this many standard deviations are ghosts:
#: far enough out that trimming good residuals biases the variance < 0.2 %.
NETWORK_GATE_K = 4.0
#: Degrees of freedom of the weak prior that keeps unidentified variance
#: combinations in place in :func:`network_noise` (far below :data:`MIN_DOF`).
_WEAK_DOF = 1e-3
#: Fewest degrees of freedom for a component to count as identified (about
#: 14 % relative standard error on its sigma).
MIN_DOF = 25.0
#: Residuals beyond this many robust sigmas are ghosts (trimmed).
TRIM_K = 3.0
#: Significance level of the homogeneity test that pools the nodes' estimates.
POOL_LEVEL = 0.05


# ------------------------------------------------------------------ robust scale
def _normal_cdf(x: float) -> float:
    return 0.5 * (1.0 + math.erf(x / math.sqrt(2.0)))


def _trim_factor(k: float) -> float:
    """``E[e^2 | |e| < k] / sigma^2`` for a normal ``e``."""
    pdf = math.exp(-0.5 * k * k) / math.sqrt(2.0 * math.pi)
    return 1.0 - 2.0 * k * pdf / (2.0 * _normal_cdf(k) - 1.0)


def trimmed_scale(e: NDArray, denom: NDArray | None = None, *, k: float = TRIM_K,
                  rounds: int = 6) -> tuple[float, int]:
    """Robust ``sqrt(sum e^2 / sum denom)`` (``denom`` 1 by default): a median
    start, then ``rounds`` of trimming at ``k`` sigmas with the truncation
    corrected. Returns (sigma, residuals kept); NaN, 0 for no residual."""
    e = np.asarray(e, dtype=float)
    d = np.ones_like(e) if denom is None else np.asarray(denom, dtype=float)
    good = np.isfinite(e) & (d > 0)
    e, d = e[good], d[good]
    if e.size == 0:
        return float("nan"), 0
    z = e / np.sqrt(d)
    s = 1.4826 * float(np.median(np.abs(z)))
    if not s > 0:
        s = float(np.sqrt(np.mean(z**2)))
    keep = np.ones(e.size, bool)
    factor = _trim_factor(k)
    for _ in range(rounds):
        if not s > 0:
            break
        keep = np.abs(z) <= k * s
        s = float(np.sqrt(np.sum(e[keep] ** 2) / (factor * np.sum(d[keep]))))
    return s, int(np.count_nonzero(keep))


# ------------------------------------------------------------------ temporal
def _difference_weights(order: int) -> NDArray:
    c = np.array([(-1) ** (order - j) * math.comb(order, j) for j in range(order + 1)], float)
    return c / np.sqrt(np.sum(c**2))


#: A difference within this fraction of its values' size is a difference of
#: repeated values (zero up to rounding).
_REPEAT_RTOL = 1e-12


def temporal_noise(detections: Detections, *, order: int = TEMPORAL_ORDER,
                   k: float = TRIM_K, remove_ghosts: bool = True) -> tuple[NDArray, NDArray]:
    """Each component's sigma from ``order``-th differences of one node's own
    centroids on runs of consecutive frames (module doc): returns
    ``(sigmas (3,), counts (3,))``, NaN and 0 where there is no run of
    ``order + 1`` frames. The spatial frequency is unwrapped along each run.
    ``remove_ghosts``: the :func:`ghost_rows` leave first (a gap each: one
    ghost would otherwise spoil ``order + 1`` differences). A component
    whose values mostly repeat (more than half its differences zero: values
    rounded coarsely) is not identified, NaN and 0."""
    if not isinstance(detections, Detections):
        raise ValidationError(f"detections must be Detections, got {type(detections).__name__}")
    if remove_ghosts:
        detections = detections.select(~ghost_rows(detections))
    w = _difference_weights(order)
    parts, zeros = [], []
    for rows in _sequences(detections):
        frames = detections.frame[rows]
        breaks = np.nonzero(np.diff(frames) != 1)[0] + 1
        for run in np.split(rows, breaks):
            if run.size <= order:
                continue
            z = detections.measurements[run]
            z[:, 1] = np.unwrap(z[:, 1])
            windows = np.lib.stride_tricks.sliding_window_view(z, order + 1, axis=0)
            parts.append(windows @ w)                       # (runs - order, 3)
            # a difference of repeated values is zero up to rounding
            zeros.append(np.abs(parts[-1]) <= _REPEAT_RTOL * np.max(np.abs(z), axis=0))
    if not parts:
        return np.full(3, np.nan), np.zeros(3, np.int64)
    e = np.concatenate(parts)
    fits = [trimmed_scale(e[:, c], k=k) for c in range(3)]
    sig = np.array([f[0] for f in fits])
    counts = np.array([f[1] for f in fits], np.int64)
    # Mostly repeated values (a logger rounding ranges to whole metres): the
    # trimmed scale of the differences collapses on the zeros to ~1e-16, a
    # sigma the data do not have. Not identified (the cross-node residuals,
    # which see the rounding, can still identify it).
    repeated = np.mean(np.concatenate(zeros), axis=0) > 0.5
    sig[repeated], counts[repeated] = np.nan, 0
    return sig, counts


# ------------------------------------------------------------------ network
def _frame_information(z, p, theta, keep, prior_w):
    """Residuals, REML score and information of one round at variances
    ``theta (N, 3)``: per frame ``R = W - W J C J^T W`` (``C`` the state's
    covariance), score ``0.5 sum (-R_ii + (w_i e_i)^2)``, information
    ``0.5 sum R_ij^2``, over the measurements ``i = 3 node + component``."""
    f, n, _ = z.shape
    w = np.where(keep, 1.0 / theta[None], 0.0)
    _, e, jac, cov = solve_frame_states(z, p, w, prior_w)
    w, jac, cov = without_unsolved(w, jac, cov)
    wf = w.reshape(f, 3 * n)
    wj = wf[..., None] * jac.reshape(f, 3 * n, 4)
    r = -np.einsum("fia,fab,fjb->fij", wj, cov, wj)
    r[:, np.arange(3 * n), np.arange(3 * n)] += wf
    ef = np.nan_to_num(e.reshape(f, 3 * n)) * (wf > 0)
    diag = np.einsum("fii->fi", r)
    score = 0.5 * np.sum(-diag + (wf * ef) ** 2, axis=0)
    info = 0.5 * np.einsum("fij,fij->ij", r, r)
    # standardized residuals: W e ~ N(0, R) at the true variances; rescaled
    # by their median so that the ghost gate holds while theta is still off
    # (only where the measurement is checked: redundancy 1 - h = R_ii / w_i >= 5 %)
    checked = (wf > 0) & (diag > 0.05 * wf)
    z_std = np.where(checked, wf * ef / np.sqrt(np.where(checked, diag, 1.0)), 0.0)
    for i in range(3 * n):
        col = np.abs(z_std[checked[:, i], i])
        if col.size:
            z_std[:, i] /= max(1.4826 * float(np.median(col)), 1e-12)
    return score, info, z_std.reshape(f, n, 3)


def _scoring_step(theta, score, info, t_theta, t_dof):
    """One Fisher-scoring step on the network likelihood plus the temporal
    estimates (independent observations of theta with variance
    ``2 theta^2 / dof``); returns the new theta and its covariance. A weak
    prior on ``log theta`` (:data:`_WEAK_DOF` dof) keeps combinations that
    nothing identifies where they are, with a variance that says so."""
    th = theta.ravel()
    d_t = np.where(np.isfinite(t_theta) & (t_dof > 0), t_dof / (2.0 * th**2), 0.0)
    tot_s = score + d_t * np.where(np.isfinite(t_theta), t_theta - th, 0.0)
    tot_i = info + np.diag(d_t)
    scaled = th[:, None] * tot_i * th[None, :] + np.eye(th.size) * (_WEAK_DOF / 2.0)
    inv = np.linalg.inv(scaled)
    step = th * (inv @ (th * tot_s))
    new = np.clip(th + step, th / 4.0, th * 4.0)
    return new.reshape(theta.shape), th[:, None] * inv * th[None, :]


def network_noise(detections: Mapping[str, Detections], poses: Mapping[str, NDArray], *,
                  initial: MeasurementNoise = MeasurementNoise(),
                  temporal: tuple[NDArray, NDArray] | None = None, n_rounds: int = 10,
                  k: float = NETWORK_GATE_K) -> tuple[NDArray, NDArray, NDArray]:
    """Per node and component, the sigma from each frame's least-squares
    residuals at the given poses (module doc): REML by Fisher scoring on the
    per-frame residuals, optionally with the nodes' temporal estimates as
    extra observations.

    detections : name -> one node's centroids, frames on a common clock
        (lags removed); frames with several centroids of a node are skipped.
    poses : name -> (3,) pose of every node in ``detections``.
    temporal : optional ``(sigmas (N, 3), dof (N, 3))`` of the nodes'
        :func:`temporal_noise` (NaN / 0 where none), combined in.
    Returns ``(sigmas (N, 3), dof (N, 3), counts (N,))`` in the order of
    ``detections``: ``dof = 2 sigma^4 / var(sigma^2)`` from the information
    (relative variance of a sigma about ``1 / (2 dof)``; 0 where nothing
    identifies it), counts the frames of cross-node residuals kept. Two nodes
    that see one coordinate the same way (range against range) check only the
    sum of their variances: the information says so (small dof), and the
    temporal estimates separate them.
    """
    names = list(detections)
    if len(names) < 2:
        raise ValidationError(f"network_noise needs at least two nodes, got {names!r}")
    missing = [n for n in names if n not in poses]
    if missing:
        raise ValidationError(f"network_noise: no pose for nodes {missing}")
    nn = len(names)
    if temporal is None:
        temporal = (np.full((nn, 3), np.nan), np.zeros((nn, 3)))
    t_sig = np.asarray(temporal[0], dtype=float)
    t_theta, t_dof = (t_sig**2).ravel(), np.asarray(temporal[1], dtype=float).ravel()
    frames, z = _frame_table(detections, names)
    theta = np.where(np.isfinite(t_sig), t_sig**2, np.tile(initial.sigmas**2, (nn, 1)))
    p = np.array([np.asarray(poses[n], dtype=float) for n in names])
    keep = np.broadcast_to(np.isfinite(z[..., :1]), z.shape)
    prior_w = 1.0 / np.array([1e3, 1e3, 1e3, 1e3]) ** 2
    score, info = np.zeros(3 * nn), np.zeros((3 * nn, 3 * nn))
    for _ in range(n_rounds if frames.size else 1):
        if frames.size:
            score, info, z_std = _frame_information(z, p, theta, keep, prior_w)
            # Ghosts (a component beyond k standard deviations) leave the next round.
            row = np.all(np.abs(z_std) <= k, axis=-1, keepdims=True)
        at = theta
        theta, cov = _scoring_step(theta, score, info, t_theta, t_dof)
        if frames.size:  # once out, out (a left-out row has no residual to re-test)
            keep = np.broadcast_to(row, z.shape) & keep
    # relative variance at the theta the covariance was evaluated at
    var = np.diag(cov).reshape(nn, 3) / at**2
    dof = np.where(var > 0, 2.0 / np.maximum(var, 1e-300), 0.0)
    counts = np.sum(keep[..., 0], axis=0).astype(np.int64)
    return np.sqrt(theta), dof, counts


# ------------------------------------------------------------------ combined
def _reason(component: int, net_dof: float | None, n_temporal: int, n_nodes: int,
            min_dof: float) -> str:
    """Why a component is not identified, in words."""
    if net_dof is None:
        why = ["no node poses for a cross-node check"]
    elif component == 2 and n_nodes == 2 and net_dof < 1.0:
        why = ["two nodes' Dopplers fix each frame's velocity exactly (no cross-node check)"]
    elif component == 2:
        why = [f"cross-node residuals and the Doppler differences with the target's motion "
               f"fitted across the nodes carry {net_dof:.1f} dof"]
    else:
        why = [f"cross-node residuals and own sequence carry {net_dof:.1f} dof"]
    why.append(f"{n_temporal} usable differences of its own centroid sequence "
               f"({n_temporal / KAPPA_4:.1f} dof); {min_dof:g} dof needed")
    return "; ".join(why)


def _aligned(recording: Recording, names, lag_frames) -> dict[str, Detections]:
    out = {}
    for n in names:
        det = recording.nodes[n].centroids
        lag = int((lag_frames or {}).get(n, 0))
        out[n] = Detections(frame=det.frame - lag, range_m=det.range_m, omega_rad=det.omega_rad,
                            doppler_mps=det.doppler_mps, target_id=det.target_id)
    return out


def _poses_for(recording: Recording, names, poses) -> dict[str, NDArray] | None:
    if poses is not None:
        got = {n: np.asarray(poses[n], dtype=float) for n in names if n in poses}
    else:
        got = {n: np.asarray(recording.nodes[n].pose, dtype=float) for n in names
               if recording.nodes[n].pose is not None}
    return got if len(got) >= 2 else None


def estimate_noise(
    recording: Recording,
    *,
    poses: Mapping[str, NDArray] | None = None,
    lag_frames: Mapping[str, int] | None = None,
    method: Literal["auto", "network", "temporal"] = "auto",
    fallback: MeasurementNoise = MeasurementNoise(),
    min_dof: float = MIN_DOF,
    pool: bool = True,
) -> NoiseEstimate:
    """Every node's measurement noise from ``recording``'s centroids (module doc).

    poses : name -> (3,) node pose for the network estimator; default the
        poses stored on the nodes. Nodes without a pose (or fewer than two
        with one) get the temporal estimator alone.
    lag_frames : name -> frame lag (node frame k + lag = reference frame k),
        e.g. :attr:`RecordingCalibration.lag_frames`; default 0.
    method : ``"auto"`` combines both estimators, or only ``"network"`` /
        ``"temporal"``.
    fallback : the sigmas reported (as not identified) for a component the
        data cannot identify; default the paper's.
    min_dof : degrees of freedom a component needs to count as identified.
    pool : share a component's pooled sigma among the nodes whose estimates
        agree (module doc).
    Never raises on data that say nothing: everything is then reported not
    identified, with the reason.
    """
    if method not in ("auto", "network", "temporal"):
        raise ValidationError(f"method={method!r} must be 'auto', 'network' or 'temporal'")
    if not isinstance(fallback, MeasurementNoise):
        raise ValidationError(f"fallback must be a MeasurementNoise, got {fallback!r}")
    if not (np.isfinite(min_dof) and min_dof > 0):
        raise ValidationError(f"min_dof={min_dof!r} must be finite and > 0")
    all_names = list(recording.node_names)
    names = [n for n in all_names if recording.nodes[n].centroids is not None
             and len(recording.nodes[n].centroids) > 0]
    dets = _aligned(recording, names, lag_frames)
    dets = {n: d.select(~ghost_rows(d)) for n, d in dets.items()}
    tmp = ({n: temporal_noise(dets[n], remove_ghosts=False) for n in names}
           if method != "network" else {})
    parts = _temporal_parts(tmp)
    net_poses = _poses_for(recording, names, poses) if method != "temporal" else None
    parts.update(_network_parts(dets, net_poses, tmp, fallback, method, min_dof))
    if pool:
        _pool(parts, min_dof)
    nodes = {n: _node_estimate(parts.get(n), tmp.get(n), len(names), fallback, min_dof)
             for n in all_names}
    label = {"auto": "network+temporal", "network": "network", "temporal": "temporal"}[method]
    n_id = sum(sum(e.identified) for e in nodes.values())
    msg = (f"noise from the data ({label}): {n_id} of {3 * len(all_names)} node sigmas "
           f"identified" + ("; no node poses: temporal estimate only"
                            if net_poses is None and method != "temporal" else ""))
    est = NoiseEstimate(nodes=nodes, fallback=fallback, method=label, message=msg)
    return with_tails(est, _aligned(recording, names, lag_frames), net_poses)


def _temporal_parts(tmp) -> dict:
    """name -> [sigmas (3,), dof (3,), counts (3,), method, network dof]."""
    return {n: [np.array(s), c / KAPPA_4, np.array(c), "temporal", None]
            for n, (s, c) in tmp.items()}


def _network_parts(dets, poses, tmp, fallback, method, min_dof=MIN_DOF) -> dict:
    """The network estimator (with the temporal estimates combined in, unless
    ``method="network"``) of the nodes with a pose; {} without poses."""
    if poses is None:
        return {}
    names = [n for n in dets if n in poses]
    if len(names) < 2:
        return {}
    t_sig = np.array([tmp[n][0] if n in tmp else np.full(3, np.nan) for n in names])
    t_cnt = np.array([tmp[n][1] if n in tmp else np.zeros(3) for n in names])
    init = np.where(np.isfinite(t_sig), t_sig, fallback.sigmas)
    init = np.sqrt(np.mean(init**2, axis=0))
    t_dof = t_cnt / KAPPA_4
    if method == "auto":
        t_sig, t_dof, t_cnt = _with_motion_doppler({n: dets[n] for n in names}, poses, t_sig,
                                                   t_dof, t_cnt, init, min_dof)
    sig, dof, counts = network_noise(
        {n: dets[n] for n in names}, poses,
        initial=MeasurementNoise(range_m=init[0], omega_rad=init[1], doppler_mps=init[2]),
        temporal=(t_sig, t_dof) if method == "auto" else None)
    label = "network+temporal" if method == "auto" else "network"
    return {n: [sig[j], dof[j], counts[j] + t_cnt[j].astype(np.int64), label, dof[j]]
            for j, n in enumerate(names)}


def _with_motion_doppler(dets, poses, t_sig, t_dof, t_cnt, init, min_dof=MIN_DOF):
    """The nodes' temporal Doppler estimates replaced by
    :func:`~.motion.motion_doppler_noise` (the target's motion fitted
    jointly across the nodes, at each frame's least-squares state) where
    that estimate is identified (``min_dof``) or carries more dof than the
    temporal one; the others kept. A motion estimate with a handful of dof
    (a body's micro-Doppler makes its Doppler rough from frame to frame, so
    few rows pass its gate) must not throw away a temporal estimate of ~80
    dof: the fusion would fall back to the paper's sigma, half the real
    one, and its velocity covariance would be too small.
    Returns new ``(t_sig, t_dof, t_cnt)``."""
    names = list(dets)
    frames, z = _frame_table(dets, names)
    if frames.size == 0:
        return t_sig, t_dof, t_cnt
    p = np.array([np.asarray(poses[n], dtype=float) for n in names])
    w = np.where(np.isfinite(z), 1.0 / init[None, None, :] ** 2, 0.0)
    states = solve_frame_states(z, p, w, np.full(4, 1e-6))[0]
    sig, dof, counts = motion_doppler_noise(dets, poses, states, frames,
                                            initial=np.full(len(names), init[2]))
    t_sig, t_dof, t_cnt = t_sig.copy(), t_dof.copy(), t_cnt.copy()
    use = np.isfinite(sig) & (sig > 0) & ((dof >= min_dof) | (dof >= t_dof[:, 2]))
    t_sig[use, 2], t_dof[use, 2], t_cnt[use, 2] = sig[use], dof[use], counts[use]
    return t_sig, t_dof, t_cnt


def _pool(parts: dict, min_dof: float) -> None:
    """Replace each component's sigma by the nodes' pooled value where their
    identified estimates are homogeneous (module doc); in place."""
    for c in range(3):
        rows = [p for p in parts.values() if np.isfinite(p[0][c]) and p[1][c] >= min_dof]
        if len(rows) < 2:
            continue
        dof = np.array([r[1][c] for r in rows])
        log_s = np.log([r[0][c] for r in rows])
        pooled = 0.5 * np.log(np.sum(dof * np.exp(2 * log_s)) / np.sum(dof))
        stat = float(np.sum(2.0 * dof * (log_s - pooled) ** 2))
        if stat <= chi2_gate(1.0 - POOL_LEVEL, len(rows) - 1):
            for r in rows:
                r[0] = np.array(r[0], dtype=float)
                r[0][c] = float(np.exp(pooled))
                if not r[3].endswith("pooled"):
                    r[3] += ", pooled"


def _node_estimate(part, tmp, n_nodes, fallback, min_dof) -> NodeNoiseEstimate:
    if part is None:
        return NodeNoiseEstimate(noise=fallback, identified=(False, False, False),
                                 n_residuals=(0, 0, 0), method="none",
                                 reasons=("no centroids",) * 3)
    sig_in, dof, counts, how, net_dof = part
    sig, cnt, ident, reasons = [], [], [], []
    for c in range(3):
        ok = bool(np.isfinite(sig_in[c]) and sig_in[c] > 0 and dof[c] >= min_dof)
        sig.append(float(sig_in[c]) if ok else float(fallback.sigmas[c]))
        cnt.append(int(counts[c]) if ok else 0)
        ident.append(ok)
        n_t = 0 if tmp is None else int(tmp[1][c])
        reasons.append("" if ok else _reason(c, None if net_dof is None else float(net_dof[c]),
                                             n_t, n_nodes, min_dof))
    noise = MeasurementNoise(range_m=sig[0], omega_rad=sig[1], doppler_mps=sig[2])
    return NodeNoiseEstimate(noise=noise, identified=tuple(ident), n_residuals=tuple(cnt),
                             method=how if any(ident) else "none", reasons=tuple(reasons))
