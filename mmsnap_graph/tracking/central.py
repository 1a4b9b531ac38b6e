"""Central tracker fed by one-shot estimates (paper Sec. II, "inputs to a
centralized tracker").

Each frame's fused targets (:class:`mmsnap_graph.fusion.sequence.FusedSequence`)
are measurements of the full state ``(x_m, y_m, vx_mps, vy_mps)`` with their
covariance, in the global frame: a linear Kalman filter with the
constant-velocity model of :mod:`factors.motion` (``F = [[I, T I], [0, I]]``,
white-acceleration ``Q = sigma_a^2 [[T^4/4, T^3/2], [T^3/2, T^2]]`` per axis).

**The prior must not be counted twice.** A MAP estimate contains the one-shot
prior (paper eq. 16) once per frame; fed as a measurement frame after frame,
the prior would be multiplied in again and again and the filter would grow
confident of the prior mean, most visibly in the cross-line velocity of a
degenerate geometry, which only the prior bounds. The tracker therefore
(``remove_prior=True``) turns each MAP estimate back into the information of
the measurements alone, exact for the linearized problem: with ``P`` the
Laplace covariance and ``Lambda_p``, ``m`` the prior's information and mean,

.. math::

    \\Lambda_z = P^{-1} - \\Lambda_p, \\qquad
    \\eta_z = P^{-1} \\hat x - \\Lambda_p m

(the gradient of the prior at the MAP equals minus the likelihood's), and
updates in information form, ``P^+ = (P^{-1}_- + \\Lambda_z)^{-1}``,
``x^+ = P^+ (P^{-1}_- x_- + \\eta_z)``. A frame seen by one node gives a
rank-3 ``Lambda_z``, which the information form takes as it is. ML estimates
(``prior=None``) are used with ``Lambda_z = P^{-1}``.

:class:`FixedLagTracker` is the same model as a GTSAM fixed-lag smoother
(one target), for smoothing and as a cross-check of the filter.

Data association between tracks and the frame's estimates: gated
(chi-square, 2 dof on position) global nearest neighbour with
:func:`scipy.optimize.linear_sum_assignment`; an unassigned successful
estimate starts a track (from that estimate, its velocity covariance floored
at ``init_velocity_sigma_mps``); a track is deleted after ``max_misses``
consecutive frames without an estimate.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import linear_sum_assignment
from tqdm import tqdm

from factors.motion import cv_process_noise, cv_transition

from ..errors import ConfigurationError, ValidationError
from ..data.recording import Tracks
from .._linalg import symmetrize
from .._validation import as_float_array, check_finite
from .ekf import config_integer, config_number

__all__ = [
    "spd_inverse_4x4",
    "CentralConfig",
    "CentralTracker",
    "FixedLagTracker",
    "measurement_information",
    "track_fused",
]


def _check_estimates(states: ArrayLike, covariances: ArrayLike) -> tuple[NDArray, NDArray]:
    """One frame's one-shot estimates, validated: ``(M, 4)`` and ``(M, 4, 4)``."""
    z = as_float_array(states, "states")
    r = as_float_array(covariances, "covariances")
    if not (np.isfinite(z).all() and np.isfinite(r).all()):  # cheap test, then the message
        check_finite(z, "states")
        check_finite(r, "covariances")
    z = z.reshape(-1, 4)
    if r.shape != (z.shape[0], 4, 4):
        raise ValidationError(f"covariances must have shape ({z.shape[0]}, 4, 4), got {r.shape}")
    return z, r


@dataclass(frozen=True, kw_only=True, slots=True)
class CentralConfig:
    """Central Kalman filter parameters.

    frame_period_s : T between frames.
    sigma_a_mps2 : white-acceleration std per axis. Default 1.0 m/s^2, as the
        per-node EKF (:class:`~mmsnap_graph.tracking.ekf.EkfConfig` says why
        the paper's 0.2 is too stiff for a person turning in a small area).
    gate_probability : chi-square gate (2 dof, position) for association.
    max_misses : consecutive frames without an estimate that end a track.
    init_velocity_sigma_mps : floor of a new track's velocity std.
    remove_prior : turn MAP estimates into measurement-only information
        (see the module docstring); ignored for ML estimates.
    """

    frame_period_s: float = 0.150
    sigma_a_mps2: float = 1.0
    gate_probability: float = 0.9999
    max_misses: int = 5
    init_velocity_sigma_mps: float = 1.0
    remove_prior: bool = True

    def __post_init__(self) -> None:
        for name in ("frame_period_s", "sigma_a_mps2", "gate_probability",
                     "init_velocity_sigma_mps"):
            object.__setattr__(self, name, config_number(self, name))
        object.__setattr__(self, "max_misses", config_integer(self, "max_misses"))
        if not isinstance(self.remove_prior, (bool, np.bool_)):
            raise ConfigurationError(f"CentralConfig.remove_prior={self.remove_prior!r} must be "
                                     "True or False")
        for name in ("frame_period_s", "init_velocity_sigma_mps"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ConfigurationError(f"{name}={v!r} must be finite and > 0")
        if not (np.isfinite(self.sigma_a_mps2) and self.sigma_a_mps2 >= 0):
            raise ConfigurationError(f"sigma_a_mps2={self.sigma_a_mps2!r} must be finite and >= 0")
        if not 0 < self.gate_probability < 1:
            raise ConfigurationError(f"gate_probability={self.gate_probability!r} must be in (0, 1)")
        if int(self.max_misses) != self.max_misses or self.max_misses < 1:
            raise ConfigurationError(f"max_misses={self.max_misses!r} must be an integer >= 1")


def _cholesky_4x4(a: list[float]) -> tuple[float, ...] | None:
    """Lower Cholesky factor ``(l00, l10, l11, l20, l21, l22, l30, l31, l32,
    l33)`` of a symmetric 4x4 matrix given row-major (16 floats), unrolled in
    plain floats; None when it is not positive definite (a pivot not above
    1e-14 times its diagonal entry, or not finite)."""
    a00, a11, a22, a33 = a[0], a[5], a[10], a[15]
    if not (a00 > 0.0 and a11 > 0.0 and a22 > 0.0 and a33 > 0.0):
        return None
    l00 = math.sqrt(a00)
    l10, l20, l30 = a[4] / l00, a[8] / l00, a[12] / l00
    d = a11 - l10 * l10
    if not d > 1e-14 * a11:
        return None
    l11 = math.sqrt(d)
    l21 = (a[9] - l20 * l10) / l11
    l31 = (a[13] - l30 * l10) / l11
    d = a22 - l20 * l20 - l21 * l21
    if not d > 1e-14 * a22:
        return None
    l22 = math.sqrt(d)
    l32 = (a[14] - l30 * l20 - l31 * l21) / l22
    d = a33 - l30 * l30 - l31 * l31 - l32 * l32
    if not (d > 1e-14 * a33 and math.isfinite(d)):
        return None
    return l00, l10, l11, l20, l21, l22, l30, l31, l32, math.sqrt(d)


def spd_inverse_4x4(p: NDArray) -> NDArray:
    """Inverse (4, 4) of a symmetric positive-definite 4x4 matrix as
    ``L^-T L^-1`` from its Cholesky factor, exactly symmetric, in plain
    floats (a tracker step inverts a few 4x4 matrices; numpy's per-call
    cost is larger than the arithmetic). Raises ``LinAlgError`` when ``p``
    is not positive definite."""
    lo = _cholesky_4x4(p.ravel().tolist())
    if lo is None:
        raise np.linalg.LinAlgError("matrix is not positive definite")
    l00, l10, l11, l20, l21, l22, l30, l31, l32, l33 = lo
    m00, m11, m22, m33 = 1.0 / l00, 1.0 / l11, 1.0 / l22, 1.0 / l33
    m10 = -l10 * m00 * m11
    m21 = -l21 * m11 * m22
    m20 = -(l20 * m00 + l21 * m10) * m22
    m32 = -l32 * m22 * m33
    m31 = -(l31 * m11 + l32 * m21) * m33
    m30 = -(l30 * m00 + l31 * m10 + l32 * m20) * m33
    c01 = m10 * m11 + m20 * m21 + m30 * m31
    c02 = m20 * m22 + m30 * m32
    c12 = m21 * m22 + m31 * m32
    c03, c13, c23 = m30 * m33, m31 * m33, m32 * m33
    return np.array(((m00 * m00 + m10 * m10 + m20 * m20 + m30 * m30, c01, c02, c03),
                     (c01, m11 * m11 + m21 * m21 + m31 * m31, c12, c13),
                     (c02, c12, m22 * m22 + m32 * m32, c23),
                     (c03, c13, c23, m33 * m33)))



def _gate_2dof(probability: float) -> float:
    """``chi2.ppf(p, 2)`` in closed form: ``-2 log(1 - p)``."""
    return -2.0 * math.log1p(-float(probability))


def _mahalanobis2(d: NDArray, s: NDArray) -> float:
    """``d^T s^-1 d`` for a 2-vector and a 2x2 matrix, in closed form (inf
    when ``s`` is singular or not positive definite)."""
    det = s[0, 0] * s[1, 1] - s[0, 1] * s[1, 0]
    if not det > 0:
        return math.inf
    return float((s[1, 1] * d[0] ** 2 - (s[0, 1] + s[1, 0]) * d[0] * d[1] + s[0, 0] * d[1] ** 2)
                 / det)


def measurement_information(
    state: ArrayLike,
    covariance: ArrayLike,
    prior_mean: ArrayLike | None = None,
    prior_sigmas: ArrayLike | None = None,
) -> tuple[NDArray, NDArray]:
    """Information ``(Lambda_z (4, 4), eta_z (4,))`` of the measurements alone
    in a one-shot estimate (module docstring); without a prior, of the
    estimate itself. Negative eigenvalues from rounding (directions the prior
    alone determined) are clipped to zero."""
    x = np.asarray(state, dtype=float)
    info = spd_inverse_4x4(symmetrize(np.asarray(covariance, dtype=float)))
    eta = info @ x
    if prior_mean is not None:
        lam_p = 1.0 / np.asarray(prior_sigmas, dtype=float) ** 2
        info = info - np.diag(lam_p)
        eta = eta - lam_p * np.asarray(prior_mean, dtype=float)
        # Positive definite (the common case): no eigenvalue to clip.
        if _cholesky_4x4(info.ravel().tolist()) is None:
            w, v = np.linalg.eigh(symmetrize(info))
            info = symmetrize((v * np.maximum(w, 0.0)) @ v.T)
    return info, eta


@dataclass(slots=True)
class _Track:
    track_id: int
    x: NDArray
    p: NDArray
    misses: int = 0


class CentralTracker:
    """Constant-velocity Kalman filter over one-shot estimates, several targets.

    ``step(states, covariances, frame_period_s)`` advances one frame and returns the
    live tracks ``[(track_id, x (4,), P (4, 4)), ...]`` after the update.
    """

    def __init__(self, config: CentralConfig | None = None, *, prior_mean: ArrayLike | None = None,
                 prior_sigmas: ArrayLike | None = None) -> None:
        self.config = CentralConfig() if config is None else config
        if (prior_mean is None) != (prior_sigmas is None):
            raise ValidationError("prior_mean and prior_sigmas go together (both or neither)")
        self.prior_mean = None if prior_mean is None else np.asarray(prior_mean, dtype=float)
        self.prior_sigmas = None if prior_sigmas is None else np.asarray(prior_sigmas, dtype=float)
        self._tracks: list[_Track] = []
        self._next_id = 0
        self._gate = _gate_2dof(self.config.gate_probability)
        self._motion: tuple | None = None  # (period, F, Q) of the last step

    @property
    def tracks(self) -> list[tuple[int, NDArray, NDArray]]:
        return [(t.track_id, t.x.copy(), t.p.copy()) for t in self._tracks]

    def _information(self, x, p):
        if self.config.remove_prior and self.prior_mean is not None:
            return measurement_information(x, p, self.prior_mean, self.prior_sigmas)
        return measurement_information(x, p)

    def step(self, states: ArrayLike, covariances: ArrayLike, frame_period_s: float | None = None):
        """One frame: predict every track, associate, update, start and end tracks.

        states : (M, 4) one-shot estimates of this frame (successful ones only);
        covariances : (M, 4, 4); frame_period_s : time since the last step
        (default ``config.frame_period_s``).
        """
        cfg = self.config
        z, r = _check_estimates(states, covariances)
        t = cfg.frame_period_s if frame_period_s is None else float(frame_period_s)
        if self._motion is None or self._motion[0] != t:  # frames mostly share one period
            self._motion = (t, cv_transition(t), cv_process_noise(t, cfg.sigma_a_mps2))
        _, f, q = self._motion
        for tr in self._tracks:
            tr.x = f @ tr.x
            tr.p = symmetrize(f @ tr.p @ f.T + q)
        assigned = np.full(z.shape[0], -1)
        if self._tracks and z.shape[0]:
            cost = np.full((len(self._tracks), z.shape[0]), np.inf)
            for i, tr in enumerate(self._tracks):
                for j in range(z.shape[0]):
                    m2 = _mahalanobis2(z[j, :2] - tr.x[:2], tr.p[:2, :2] + r[j, :2, :2])
                    if m2 <= self._gate:
                        cost[i, j] = m2
            finite = np.where(np.isfinite(cost), cost, 1e12)
            if finite.shape == (1, 1):  # one track, one estimate
                rows, cols = np.zeros(1, dtype=np.int64), np.zeros(1, dtype=np.int64)
            else:
                rows, cols = linear_sum_assignment(finite)
            for i, j in zip(rows, cols):
                if np.isfinite(cost[i, j]):
                    assigned[j] = i
        hit = np.zeros(len(self._tracks), dtype=bool)
        for j in np.flatnonzero(assigned >= 0):
            tr = self._tracks[assigned[j]]
            lam_z, eta_z = self._information(z[j], r[j])
            info_pred = spd_inverse_4x4(tr.p)
            info_post = symmetrize(info_pred + lam_z)
            tr.p = spd_inverse_4x4(info_post)
            tr.x = tr.p @ (info_pred @ tr.x + eta_z)
            hit[assigned[j]] = True
        for i, tr in enumerate(self._tracks):
            tr.misses = 0 if hit[i] else tr.misses + 1
        self._tracks = [tr for tr in self._tracks if tr.misses < cfg.max_misses]
        for j in np.flatnonzero(assigned < 0):
            p0 = symmetrize(r[j].copy())
            v_floor = cfg.init_velocity_sigma_mps**2
            for k in (2, 3):
                p0[k, k] = max(p0[k, k], v_floor)
            self._tracks.append(_Track(track_id=self._next_id, x=z[j].copy(), p=p0))
            self._next_id += 1
        return self.tracks


def _information_error(a, b, this, values, jacobians):
    x = values.atVector(this.keys()[0])
    if jacobians is not None:
        jacobians[0] = a
    return a @ x - b


class FixedLagTracker:
    """One target, GTSAM fixed-lag smoother (``gtsam.BatchFixedLagSmoother``)
    over one-shot estimates: the central tracker as a factor graph.

    Variables: one ``Vector4`` state per frame. Factors: the constant-velocity
    factor of :func:`factors.gtsam_factors.constant_velocity_factor` between
    consecutive states (its full-rank continuous white-noise form, see its
    docstring), and per estimate a factor ``1/2 |A x - b|^2`` carrying the
    estimate's measurement information (``A^T A = Lambda_z``,
    ``A^T b = eta_z``, :func:`measurement_information`; the prior removed as
    in :class:`CentralTracker`, rank 3 for a single node). The first estimate
    starts the track as a prior factor (velocity sigma floored at
    ``config.init_velocity_sigma_mps``). States older than ``lag_s`` are
    marginalized. The returned covariance is ``gtsam.Marginals`` on the
    smoother's current graph.

    Only one target: with several estimates in a frame the one nearest the
    prediction inside the gate is used. ``step`` returns ``[(0, x, P)]`` for
    the newest state once the track has started, else ``[]``.
    """

    def __init__(self, config: CentralConfig | None = None, *, lag_s: float = 1.5,
                 prior_mean: ArrayLike | None = None, prior_sigmas: ArrayLike | None = None) -> None:
        # Function-level: keeps GTSAM off the import path of the tracking package.
        import gtsam

        self.config = CentralConfig() if config is None else config
        if not (np.isfinite(lag_s) and lag_s > 0):
            raise ConfigurationError(f"lag_s={lag_s!r} must be finite and > 0")
        if (prior_mean is None) != (prior_sigmas is None):
            raise ValidationError("prior_mean and prior_sigmas go together (both or neither)")
        self.prior_mean = None if prior_mean is None else np.asarray(prior_mean, dtype=float)
        self.prior_sigmas = None if prior_sigmas is None else np.asarray(prior_sigmas, dtype=float)
        self._gtsam = gtsam
        self._smoother = gtsam.BatchFixedLagSmoother(float(lag_s))
        self._key = -1
        self._time_s = 0.0
        self._x: NDArray | None = None
        self._p: NDArray | None = None
        self._gate = _gate_2dof(self.config.gate_probability)

    def _measurement_factor(self, key, x, p):
        gtsam = self._gtsam
        if self.config.remove_prior and self.prior_mean is not None:
            info, eta = measurement_information(x, p, self.prior_mean, self.prior_sigmas)
        else:
            info, eta = measurement_information(x, p)
        w, v = np.linalg.eigh(info)
        keep = w > 1e-12 * max(w.max(), 1e-300)
        if not np.any(keep):
            return None
        a = np.sqrt(w[keep])[:, None] * v[:, keep].T
        b = (v[:, keep].T @ eta) / np.sqrt(w[keep])
        return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(int(keep.sum())), [key],
                                  partial(_information_error, a, b))

    def step(self, states: ArrayLike, covariances: ArrayLike, frame_period_s: float | None = None):
        """One frame; see :meth:`CentralTracker.step` for the arguments."""
        # Function-level: keeps GTSAM off the import path of the tracking package.
        from factors.gtsam_factors import constant_velocity_factor

        gtsam = self._gtsam
        cfg = self.config
        z, r = _check_estimates(states, covariances)
        t = cfg.frame_period_s if frame_period_s is None else float(frame_period_s)
        graph = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        stamps = gtsam.FixedLagSmootherKeyTimestampMap()
        if self._x is None:
            if z.shape[0] == 0:
                return []
            p0 = symmetrize(r[0].copy())
            for k in (2, 3):
                p0[k, k] = max(p0[k, k], cfg.init_velocity_sigma_mps**2)
            self._key = 0
            graph.add(gtsam.PriorFactorVector(0, z[0], gtsam.noiseModel.Gaussian.Covariance(p0)))
            values.insert(0, z[0])
        else:
            self._time_s += t
            prev, key = self._key, self._key + 1
            self._key = key
            f = cv_transition(t)
            pred = f @ self._x
            p_pred = f @ self._p @ f.T + cv_process_noise(t, cfg.sigma_a_mps2)
            graph.add(constant_velocity_factor(prev, key, t, cfg.sigma_a_mps2))
            values.insert(key, pred)
            best, best_m2 = None, self._gate
            for j in range(z.shape[0]):
                d = z[j, :2] - pred[:2]
                m2 = float(d @ np.linalg.solve(p_pred[:2, :2] + r[j, :2, :2], d))
                if m2 <= best_m2:
                    best, best_m2 = j, m2
            if best is not None:
                factor = self._measurement_factor(key, z[best], r[best])
                if factor is not None:
                    graph.add(factor)
        stamps.insert((self._key, self._time_s))
        self._smoother.update(graph, values, stamps)
        estimate = self._smoother.calculateEstimate()
        factors = self._smoother.getFactors()
        current = gtsam.NonlinearFactorGraph()
        for i in range(factors.size()):
            f = factors.at(i)
            if f is not None:
                current.add(f)
        self._x = estimate.atVector(self._key)
        self._p = symmetrize(gtsam.Marginals(current, estimate).marginalCovariance(self._key))
        return [(0, self._x.copy(), self._p.copy())]


def track_fused(fused, config: CentralConfig | None = None, *, progress: bool = False) -> Tracks:
    """Run a :class:`CentralTracker` over a :class:`~mmsnap_graph.fusion.sequence.FusedSequence`.

    Successful estimates only; MAP estimates have their prior removed
    (``config.remove_prior``). Every frame from the first to the last fused
    frame is a step (frames without estimates are prediction-only). Returns
    global-frame :class:`~mmsnap_graph.data.recording.Tracks` at every frame a
    track is alive.
    """
    cfg = CentralConfig() if config is None else config
    tracker = CentralTracker(cfg, prior_mean=fused.prior_mean, prior_sigmas=fused.prior_sigmas)
    ok = np.asarray(fused.success, dtype=bool)
    frames_ok = np.asarray(fused.frame)[ok]
    if frames_ok.size == 0:
        return Tracks.empty()
    states = np.asarray(fused.state)[ok]
    covs = np.asarray(fused.covariance)[ok]
    order = np.argsort(frames_ok, kind="stable")
    frames_ok, states, covs = frames_ok[order], states[order], covs[order]
    out_f, out_id, out_x, out_p = [], [], [], []
    frames = np.arange(frames_ok[0], frames_ok[-1] + 1)
    for f in tqdm(frames, desc="central tracker", unit="frame", disable=not progress):
        lo, hi = np.searchsorted(frames_ok, [f, f + 1])
        for tid, x, p in tracker.step(states[lo:hi], covs[lo:hi]):
            out_f.append(int(f))
            out_id.append(tid)
            out_x.append(x)
            out_p.append(p)
    if not out_f:
        return Tracks.empty()
    return Tracks(frame=np.array(out_f), track_id=np.array(out_id), state=np.array(out_x),
                  covariance=np.array(out_p))
