"""Central tracker fed by one-shot estimates (paper Sec. II, "inputs to a
centralized tracker").

Each frame's fused targets (:class:`mmsnap_graph.fusion.recording.sequence.FusedSequence`)
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
consecutive frames without an estimate, or, before association, when more
than ``max_misses + 1`` nominal frame periods (``frame_period_s``) have passed
since its last estimate (a long gap between two steps: its prediction says
nothing any more) or its predicted covariance is not positive definite.
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
from .._floats4 import cholesky_4x4, cholesky_inverse_4x4
from .._linalg import symmetrize
from .._validation import as_float_array, check_count, check_finite, check_probability, chi2_gate
from .ekf import config_integer, config_number

__all__ = [
    "spd_inverse_4x4",
    "spd_inverse_floats",
    "cv_predict_floats",
    "measurement_information_floats",
    "check_estimates",
    "CentralConfig",
    "CentralTracker",
    "FixedLagTracker",
    "measurement_information",
    "track_fused",
]


def check_estimates(states: ArrayLike, covariances: ArrayLike) -> tuple[NDArray, NDArray]:
    """One-shot estimates, validated (finite, shapes): ``(M, 4)`` and ``(M, 4, 4)``."""
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
    sigma_a_mps2 : white-acceleration std per axis. Default 1.0 m/s^2: the
        paper's 0.2 is too stiff for a person turning in a small area
        (:class:`~mmsnap_graph.tracking.ekf.EkfConfig` says why; the per-node
        EKF, fed single centroids, uses 3.0).
    gate_probability : chi-square gate (2 dof, position) for association.
    max_misses : consecutive frames without an estimate that end a track;
        more than ``(max_misses + 1) * frame_period_s`` seconds without one
        end it too (a gap between steps).
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
        check_probability(self.gate_probability, "gate_probability", error=ConfigurationError)
        check_count(self.max_misses, "max_misses", error=ConfigurationError)


def spd_inverse_floats(a: list[float]) -> list[float]:
    """``a^-1`` of a symmetric positive-definite 4x4 (row-major 16 floats) as
    ``L^-T L^-1``, exactly symmetric; ``LinAlgError`` when not positive definite."""
    lo = cholesky_4x4(a)
    if lo is None:
        raise np.linalg.LinAlgError("matrix is not positive definite")
    return cholesky_inverse_4x4(lo)


def _matvec(a: list[float], x: list[float]) -> list[float]:
    """``a x`` of a row-major 4x4 and a 4-vector, in floats (written out: a
    tracker step makes a few, where a comprehension's call is most of the cost)."""
    x0, x1, x2, x3 = x
    return [a[0] * x0 + a[1] * x1 + a[2] * x2 + a[3] * x3,
            a[4] * x0 + a[5] * x1 + a[6] * x2 + a[7] * x3,
            a[8] * x0 + a[9] * x1 + a[10] * x2 + a[11] * x3,
            a[12] * x0 + a[13] * x1 + a[14] * x2 + a[15] * x3]


def _symmetric(a: list[float]) -> list[float]:
    """``(a + a^T) / 2`` of a row-major 4x4."""
    a00, a01, a02, a03, a10, a11, a12, a13, a20, a21, a22, a23, a30, a31, a32, a33 = a
    s01, s02, s03 = 0.5 * (a01 + a10), 0.5 * (a02 + a20), 0.5 * (a03 + a30)
    s12, s13, s23 = 0.5 * (a12 + a21), 0.5 * (a13 + a31), 0.5 * (a23 + a32)
    return [0.5 * (a00 + a00), s01, s02, s03, s01, 0.5 * (a11 + a11), s12, s13,
            s02, s12, 0.5 * (a22 + a22), s23, s03, s13, s23, 0.5 * (a33 + a33)]


def spd_inverse_4x4(p: ArrayLike) -> NDArray:
    """Inverse (4, 4) of a symmetric positive-definite 4x4 matrix as
    ``L^-T L^-1`` from its Cholesky factor, exactly symmetric, in plain
    floats (a tracker step inverts a few 4x4 matrices; numpy's per-call
    cost is larger than the arithmetic). Raises ``LinAlgError`` when ``p``
    is not positive definite."""
    return np.array(spd_inverse_floats(np.asarray(p, dtype=float).ravel().tolist())).reshape(4, 4)


def _gate_2dof(probability: float) -> float:
    """``chi2.ppf(p, 2)`` (in closed form: ``-2 log(1 - p)``)."""
    return chi2_gate(probability, 2)


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
    x = np.asarray(state, dtype=float).tolist()
    lam_p = None if prior_mean is None else (1.0 / np.asarray(prior_sigmas, dtype=float) ** 2).tolist()
    mean = None if prior_mean is None else np.asarray(prior_mean, dtype=float).tolist()
    info, eta = measurement_information_floats(
        x, _symmetric(np.asarray(covariance, dtype=float).ravel().tolist()), mean, lam_p)
    return np.array(info).reshape(4, 4), np.array(eta)


def measurement_information_floats(x, p, mean, lam_p):
    """:func:`measurement_information` in floats: ``x`` 4, ``p`` row-major 16
    (symmetric), the prior's mean and information diagonal (4 each) or None."""
    info = spd_inverse_floats(p)
    eta = _matvec(info, x)
    if mean is not None:
        info[0] -= lam_p[0]
        info[5] -= lam_p[1]
        info[10] -= lam_p[2]
        info[15] -= lam_p[3]
        eta[0] -= lam_p[0] * mean[0]
        eta[1] -= lam_p[1] * mean[1]
        eta[2] -= lam_p[2] * mean[2]
        eta[3] -= lam_p[3] * mean[3]
        # Positive definite (the common case): no eigenvalue to clip.
        if cholesky_4x4(info) is None:
            w, v = np.linalg.eigh(np.array(info).reshape(4, 4))
            info = symmetrize((v * np.maximum(w, 0.0)) @ v.T).ravel().tolist()
    return info, eta


@dataclass(slots=True)
class _Track:
    """A live track: its state (4 floats) and covariance (16 floats, row-major)."""

    track_id: int
    x: list
    p: list
    misses: int = 0
    since_hit_s: float = 0.0


def cv_predict_floats(x: list[float], p: list[float], t: float, q: list[float]) -> tuple[list, list]:
    """The constant-velocity prediction ``(F x, F P F^T + Q)`` over ``t``, in
    floats (``F = [[I, t I], [0, I]]``; :func:`factors.motion.cv_transition`; ``q``
    the process noise as 16 row-major floats), each 4x4 row-major."""
    x0, x1, x2, x3 = x
    p00, p01, p02, p03, p10, p11, p12, p13, p20, p21, p22, p23, p30, p31, p32, p33 = p
    # A = F P: rows 0 and 1 gain t times rows 2 and 3.
    a00, a01, a02, a03 = p00 + t * p20, p01 + t * p21, p02 + t * p22, p03 + t * p23
    a10, a11, a12, a13 = p10 + t * p30, p11 + t * p31, p12 + t * p32, p13 + t * p33
    # F P F^T = A F^T: columns 0 and 1 gain t times columns 2 and 3 (then
    # symmetrized and Q added).
    o00, o01, o10, o11 = a00 + t * a02, a01 + t * a03, a10 + t * a12, a11 + t * a13
    o20, o21, o30, o31 = p20 + t * p22, p21 + t * p23, p30 + t * p32, p31 + t * p33
    c01, c02, c03 = 0.5 * (o01 + o10), 0.5 * (a02 + o20), 0.5 * (a03 + o30)
    c12, c13, c23 = 0.5 * (a12 + o21), 0.5 * (a13 + o31), 0.5 * (p23 + p32)
    return ([x0 + t * x2, x1 + t * x3, x2, x3],
            [0.5 * (o00 + o00) + q[0], c01 + q[1], c02 + q[2], c03 + q[3],
             c01 + q[4], 0.5 * (o11 + o11) + q[5], c12 + q[6], c13 + q[7],
             c02 + q[8], c12 + q[9], 0.5 * (p22 + p22) + q[10], c23 + q[11],
             c03 + q[12], c13 + q[13], c23 + q[14], 0.5 * (p33 + p33) + q[15]])


def _mahalanobis2_floats(dx: float, dy: float, a: float, b: float, c: float, d: float) -> float:
    """``(dx, dy) S^-1 (dx, dy)^T`` with ``S = [[a, b], [c, d]]`` (inf unless det > 0)."""
    det = a * d - b * c
    if not det > 0:
        return math.inf
    return (d * dx * dx - (b + c) * dx * dy + a * dy * dy) / det


class CentralTracker:
    """Constant-velocity Kalman filter over one-shot estimates, several targets.

    ``step(states, covariances, frame_period_s)`` advances one frame and returns the
    live tracks ``[(track_id, x (4,), P (4, 4)), ...]`` after the update;
    :attr:`estimate_ids` then holds, for each estimate of the step, the id of
    the track it updated or started (the person id of that estimate).
    The 4x4 algebra of a step is done in plain floats (a few tracks and
    estimates per frame: numpy's per-call cost would be most of the step).
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
        #: (M,) int64, the track id each estimate of the last step went to.
        self.estimate_ids = np.zeros(0, dtype=np.int64)
        self._gate = _gate_2dof(self.config.gate_probability)
        self._motion: tuple | None = None  # (period, Q as 16 floats) of the last step
        # The prior removed from MAP estimates (mean, information diagonal), or None.
        self._prior = None
        if self.config.remove_prior and self.prior_mean is not None:
            self._prior = (self.prior_mean.tolist(), (1.0 / self.prior_sigmas**2).tolist())

    @property
    def tracks(self) -> list[tuple[int, NDArray, NDArray]]:
        return [(t.track_id, np.array(t.x), np.array(t.p).reshape(4, 4)) for t in self._tracks]

    @property
    def n_tracks(self) -> int:
        """The live tracks."""
        return len(self._tracks)

    def track_arrays(self) -> tuple[NDArray, NDArray, NDArray]:
        """The live tracks as arrays: ``track_id (T,)`` int64, ``state (T, 4)``,
        ``covariance (T, 4, 4)`` (new arrays)."""
        tracks = self._tracks
        return (np.array([t.track_id for t in tracks], dtype=np.int64),
                np.array([t.x for t in tracks], dtype=float).reshape(-1, 4),
                np.array([t.p for t in tracks], dtype=float).reshape(-1, 4, 4))

    def step(self, states: ArrayLike, covariances: ArrayLike, frame_period_s: float | None = None):
        """One frame: predict every track, associate, update, start and end tracks.

        states : (M, 4) one-shot estimates of this frame (successful ones only);
        covariances : (M, 4, 4); frame_period_s : time since the last step
        (default ``config.frame_period_s``).
        """
        self.update(states, covariances, frame_period_s)
        return self.tracks

    def update(self, states: ArrayLike, covariances: ArrayLike,
               frame_period_s: float | None = None) -> list[int]:
        """:meth:`step` returning each estimate's track id (as
        :attr:`estimate_ids`) instead of the live tracks (the stream's step:
        it takes the tracks as arrays, :meth:`track_arrays`)."""
        self.estimate_ids = np.zeros(0, dtype=np.int64)  # until this step succeeds
        z, r = check_estimates(states, covariances)
        return self.step_ids(z.tolist(), r.reshape(-1, 16).tolist(), frame_period_s)

    def step_ids(self, states: list, covariances: list,
                 frame_period_s: float | None = None) -> list[int]:
        """:meth:`step` on estimates already checked (:func:`check_estimates`),
        as plain floats: ``states`` M lists of 4, ``covariances`` M lists of 16
        (row-major); returns each estimate's track id (as :attr:`estimate_ids`)
        instead of the live tracks (the step of :class:`~.person_ids.PersonIds`)."""
        cfg = self.config
        t = cfg.frame_period_s if frame_period_s is None else float(frame_period_s)
        if self._motion is None or self._motion[0] != t:  # frames mostly share one period
            self._motion = (t, cv_process_noise(t, cfg.sigma_a_mps2).ravel().tolist())
        q = self._motion[1]
        coast_limit_s = (cfg.max_misses + 1) * cfg.frame_period_s
        for tr in self._tracks:
            tr.x, tr.p = cv_predict_floats(tr.x, tr.p, t, q)
            tr.since_hit_s += t
        # A gap between steps longer than the coast limit, or a prediction
        # that lost positive definiteness (rounding over a huge t), ends it.
        if self._tracks:
            self._tracks = [tr for tr in self._tracks
                            if tr.since_hit_s <= coast_limit_s and cholesky_4x4(tr.p) is not None]
        zl, rl = states, covariances
        assigned = self._associate(zl, rl)
        hit = [False] * len(self._tracks)
        ids = [-1] * len(zl)
        prior = self._prior if self._prior is not None else (None, None)
        for j, i in enumerate(assigned):
            if i < 0:
                continue
            tr = self._tracks[i]
            ids[j] = tr.track_id
            lam_z, eta_z = measurement_information_floats(zl[j], _symmetric(rl[j]), *prior)
            info_pred = spd_inverse_floats(tr.p)
            tr.p = spd_inverse_floats([u + v for u, v in zip(info_pred, lam_z)])
            tr.x = _matvec(tr.p, [u + v for u, v in zip(_matvec(info_pred, tr.x), eta_z)])
            hit[i] = True
            tr.since_hit_s = 0.0
        if self._tracks:
            for i, tr in enumerate(self._tracks):
                tr.misses = 0 if hit[i] else tr.misses + 1
            self._tracks = [tr for tr in self._tracks if tr.misses < cfg.max_misses]
        v_floor = cfg.init_velocity_sigma_mps**2
        for j, i in enumerate(assigned):
            if i >= 0:
                continue
            p0 = _symmetric(rl[j])
            p0[10], p0[15] = max(p0[10], v_floor), max(p0[15], v_floor)
            self._tracks.append(_Track(track_id=self._next_id, x=list(zl[j]), p=p0))
            ids[j] = self._next_id
            self._next_id += 1
        self.estimate_ids = np.array(ids, dtype=np.int64)
        return ids

    def _associate(self, zl, rl) -> list[int]:
        """The track of each estimate (-1: none): gated (chi-square, 2 dof, on
        position) global nearest neighbour."""
        assigned = [-1] * len(zl)
        if not (self._tracks and zl):
            return assigned
        cost = [[math.inf] * len(zl) for _ in self._tracks]
        for i, tr in enumerate(self._tracks):
            x, p = tr.x, tr.p
            for j, (zj, rj) in enumerate(zip(zl, rl)):
                m2 = _mahalanobis2_floats(zj[0] - x[0], zj[1] - x[1], p[0] + rj[0], p[1] + rj[1],
                                          p[4] + rj[4], p[5] + rj[5])
                if m2 <= self._gate:
                    cost[i][j] = m2
        if len(cost) == 1 and len(zl) == 1:  # one track, one estimate
            pairs = [(0, 0)]
        else:
            arr = np.array(cost)
            rows, cols = linear_sum_assignment(np.where(np.isfinite(arr), arr, 1e12))
            pairs = zip(rows.tolist(), cols.tolist())
        for i, j in pairs:
            if math.isfinite(cost[i][j]):
                assigned[j] = i
        return assigned


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
        z, r = check_estimates(states, covariances)
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
    """Run a :class:`CentralTracker` over a :class:`~mmsnap_graph.fusion.recording.sequence.FusedSequence`.

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
