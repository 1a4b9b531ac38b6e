"""Per-node multi-target EKF in the node's local frame (paper section II-A).

State ``(x_m, y_m, vx_mps, vy_mps)`` in the node's local frame (x along the
array axis, y broadside). Motion: constant velocity with white-acceleration
noise (docs/CONVENTIONS.md, "Constant-velocity motion model"), per axis

.. math::

    F = \\begin{bmatrix} 1 & T \\\\ 0 & 1 \\end{bmatrix},\\quad
    Q = \\sigma_a^2 \\begin{bmatrix} T^4/4 & T^3/2 \\\\ T^3/2 & T^2 \\end{bmatrix}.

Motion: :mod:`factors.motion`. Measurement: ``(range_m, omega_rad, doppler_mps)`` through
:func:`factors.models.measurement_model` with the node pose ``(0, 0, 0)``
(the same model as the factor graph), spatial-frequency innovation wrapped.

Data association per frame: Mahalanobis gating (``d^2 < chi2_3(gate_probability)``),
then a global nearest-neighbour assignment (``scipy.optimize.linear_sum_assignment``
on ``d^2 + ln det S``) among gated pairs, the confirmed tracks first and the
tentative ones on the measurements left (a tentative track born from one
off-track centroid must not take the walker's next centroid from his
confirmed track: that ended a walker's track at most turns). Track
management: an unassigned measurement starts a tentative track unless it
lies in the gate of a confirmed track, of a track updated in this frame or
of one born from another measurement of this frame, or within
``body_radius_m`` of a confirmed track (a second cluster of the same body);
a tentative track is confirmed after
``confirm_hits_frames`` hits within its first ``confirm_window_s`` seconds and
deleted if it cannot be; a confirmed track is deleted after coasting
``max_coast_s`` seconds without a hit (both converted to frames with the
frame period, so the defaults hold from 5 to 30 fps). With
``doppler_wrap_mps`` the Doppler innovation is wrapped modulo twice the
unambiguous speed, as the spatial-frequency one is modulo ``2 pi``. Linear algebra: Cholesky factor of the innovation covariance and
triangular solves (no explicit inverse), Joseph-form updates, symmetrized
covariances.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import linear_sum_assignment

from factors.models import detection_covariance_local, detection_to_local, measurement_model, wrap_angle
from factors.motion import cv_process_noise, cv_transition

from ..errors import ConfigurationError, ValidationError
from ..data.recording import Detections, Tracks
from .._linalg import symmetrize
from .._validation import (as_float_array, check_count, check_finite, check_positive, chi2_gate,
                           frame_steps)

__all__ = [
    "EkfConfig",
    "config_number",
    "config_integer",
    "track_initial_state",
    "ekf_predict",
    "ekf_update",
    "wrap_innovation",
    "LocalTracker",
    "track_centroids",
    "frames_to_step",
    "MAX_RANGE_M",
    "MAX_SPEED_MPS",
]

#: Measurements beyond these (m, m/s) are not physical for a radar: a tracker
#: step ignores them (a range of 1e300 would overflow the EKF).
MAX_RANGE_M = 1e5
MAX_SPEED_MPS = 1e4
#: Bounds of the configuration: beyond them a value is a unit or typing
#: mistake and overflowed the filter (a 1e308 m/s^2 process noise squared is
#: inf; a 1e308 s window is an infinite frame count).
MAX_ACCELERATION_MPS2 = 1e3
MAX_WINDOW_S = 3600.0
MAX_FRAME_COUNT = 1_000_000

_ZERO_POSE = np.zeros(3)


def config_number(config, name: str) -> float:
    """``config.name`` as a float, when it is a real number (not a bool, a
    string or an array); else :class:`ConfigurationError` naming it."""
    value = getattr(config, name)
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer,
                                                                    np.floating)):
        raise ConfigurationError(f"{type(config).__name__}.{name}={value!r} must be a number, "
                                 f"got {type(value).__name__}")
    return float(value)


def config_integer(config, name: str) -> int:
    """``config.name`` as an int, when it is a whole number (an int or an
    integral float); else :class:`ConfigurationError` naming it."""
    value = config_number(config, name)
    if not np.isfinite(value) or value != int(value):
        raise ConfigurationError(f"{type(config).__name__}.{name}={getattr(config, name)!r} "
                                 "must be an integer")
    return int(value)


@dataclass(frozen=True, kw_only=True, slots=True)
class EkfConfig:
    """Per-node EKF and track management parameters.

    frame_period_s : T, time between frames.
    sigma_a_mps2 : white-acceleration standard deviation per axis. Default
        3.0 m/s^2. The paper's scripts use 0.2 (docs/CONVENTIONS.md, last
        section); a walker turning inside a few-metre area accelerates more
        (simulated random walks: 1.1 m/s^2 per axis, |a| 0.8 median, 2.9
        90th and 4.4 99th percentile; a white-noise acceleration model wants
        about half to all of the largest): with 0.2 the innovations left the
        gate at every turn (a 600-frame walk broke into 64 tracks per node),
        with 1.0 into 32 and 41, with 2.0 into 2 and 7, with 3.0 into 2 and 5
        (configuration C, seed 1). On the real two-person recording the mean
        normalised innovation is then 3.0 and 3.2 (chi-square(3): 3). Pass 0.2
        to reproduce the paper.
    measurement_std : (3,) std of a torso centroid's ``(range_m, omega_rad,
        doppler_mps)``. Default ``(0.05, 0.1, 0.2)``: the chain's centroid
        accuracy on simulated walkers (median position error about 4 cm,
        90th percentile 8 cm at 2-5 m), with margin. The paper's resolutions
        ``(0.035, pi / 4, 0.1807)`` (docs/CONVENTIONS.md), used as the one-shot
        fusion's sigmas, make the angle nearly uninformative to a single-node
        filter: on a simulated configuration-C walk its tracks drifted 1-4 m
        across range, against 0.2 m with the default.
    init_tangential_speed_std_mps : std of the velocity across the line of
        sight at track start (the Doppler gives only the radial part).
    gate_probability : chi-square gate probability (3 degrees of freedom).
    confirm_hits : hits that confirm a tentative track (at least).
    confirm_fraction : ... and at least this fraction of the frames of the
        confirmation window (default 0.5: 3 of 5 frames of 150 ms, 8 of 15
        at 20 fps; :attr:`confirm_hits_frames`): a count of hits alone is
        far easier for clutter to reach at a high frame rate.
    confirm_window_s : ... within this time from its first hit (default
        0.75 s: 5 frames of 150 ms, 15 at 20 fps, 4 at 5 fps).
    max_coast_s : a confirmed track coasting this long without a hit is
        deleted (default 0.75 s).
    confirm_window, max_misses : the same two thresholds in frames; when
        given (not None) they take precedence over the times. The frame
        counts in use are :attr:`confirm_window_frames` and
        :attr:`max_misses_frames` (times divided by ``frame_period_s``,
        rounded up), so that one configuration works from 5 to 30 fps.
    doppler_wrap_mps : the unambiguous speed ``U`` of the Doppler
        measurements (e.g. :func:`mmsnap_graph.radar.chain.unambiguous_speed_mps`):
        the Doppler innovation is wrapped into ``[-U, U)`` (modulo ``2 U``),
        so an aliased Doppler still updates a fast track the right way.
        None (default): not wrapped.
    body_radius_m : a centroid within this distance (m) of a confirmed
        track's position starts no track (a second cluster of the same
        body); 0 turns it off.
    """

    frame_period_s: float = 0.150
    sigma_a_mps2: float = 3.0
    measurement_std: tuple = (0.05, 0.1, 0.2)
    init_tangential_speed_std_mps: float = 1.0
    gate_probability: float = 0.997
    confirm_hits: int = 3
    confirm_fraction: float = 0.5
    confirm_window_s: float = 0.75
    max_coast_s: float = 0.75
    confirm_window: int | None = None
    max_misses: int | None = None
    doppler_wrap_mps: float | None = None
    body_radius_m: float = 0.3

    def __post_init__(self) -> None:
        for name in ("frame_period_s", "sigma_a_mps2", "init_tangential_speed_std_mps",
                     "gate_probability", "confirm_fraction", "body_radius_m"):
            object.__setattr__(self, name, config_number(self, name))
        for name in ("confirm_window_s", "max_coast_s"):
            object.__setattr__(self, name, config_number(self, name))
        for name in ("confirm_hits", "confirm_window", "max_misses"):
            if getattr(self, name) is not None or name == "confirm_hits":
                object.__setattr__(self, name, config_integer(self, name))
        if self.doppler_wrap_mps is not None:
            object.__setattr__(self, "doppler_wrap_mps", config_number(self, "doppler_wrap_mps"))
        try:
            std = tuple(float(s) for s in self.measurement_std)
        except (TypeError, ValueError):
            std = ()
        if isinstance(self.measurement_std, (str, bytes)) or len(std) != 3 or \
                not all(np.isfinite(s) and s > 0 for s in std):
            raise ConfigurationError(f"measurement_std={self.measurement_std!r} must be three "
                                     f"finite values > 0 (range_m, omega_rad, doppler_mps)")
        object.__setattr__(self, "measurement_std", std)
        for name in ("frame_period_s", "init_tangential_speed_std_mps"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ConfigurationError(f"{name}={v!r} must be finite and > 0")
        if not (np.isfinite(self.sigma_a_mps2) and self.sigma_a_mps2 >= 0):
            raise ConfigurationError(f"sigma_a_mps2={self.sigma_a_mps2!r} must be finite and >= 0")
        if not 0 < self.gate_probability < 1:
            raise ConfigurationError(f"gate_probability={self.gate_probability!r} must be in (0, 1)")
        if not (np.isfinite(self.body_radius_m) and 0 <= self.body_radius_m <= 10):
            raise ConfigurationError(f"body_radius_m={self.body_radius_m!r} must be in [0, 10] "
                                     f"(metres)")
        if not 0 <= self.confirm_fraction <= 1:
            raise ConfigurationError(f"confirm_fraction={self.confirm_fraction!r} must be in "
                                     f"[0, 1] (a fraction of the window's frames)")
        for name in ("confirm_hits", "confirm_window", "max_misses"):
            v = getattr(self, name)
            if v is None and name != "confirm_hits":
                continue
            check_count(v, name, 1, MAX_FRAME_COUNT, error=ConfigurationError)
        for name in ("confirm_window_s", "max_coast_s"):
            v = getattr(self, name)
            if isinstance(v, bool) or not (np.isfinite(v) and 0 < v <= MAX_WINDOW_S):
                raise ConfigurationError(f"{name}={v!r} must be in (0, {MAX_WINDOW_S:g}] "
                                         f"(seconds)")
        self._check_physical()

    def _check_physical(self) -> None:
        """Upper bounds of the physical values (m, m/s, m/s^2, rad)."""
        bounds = {"sigma_a_mps2": MAX_ACCELERATION_MPS2,
                  "init_tangential_speed_std_mps": MAX_SPEED_MPS,
                  "doppler_wrap_mps": MAX_SPEED_MPS}
        for name, bound in bounds.items():
            v = getattr(self, name)
            if v is not None and v > bound:
                raise ConfigurationError(f"{name}={v!r} must be <= {bound:g} (a larger value "
                                         f"is not physical; check the unit)")
        for name, v, bound in zip(("range_m", "omega_rad", "doppler_mps"), self.measurement_std,
                                  (MAX_RANGE_M, np.pi, MAX_SPEED_MPS)):
            if v > bound:
                raise ConfigurationError(f"measurement_std {name}={v!r} must be <= {bound:g}")
        if self.doppler_wrap_mps is not None and (
                isinstance(self.doppler_wrap_mps, bool)
                or not (np.isfinite(self.doppler_wrap_mps) and self.doppler_wrap_mps > 0)):
            raise ConfigurationError(f"doppler_wrap_mps={self.doppler_wrap_mps!r} must be "
                                     f"finite and > 0, or None")
        if self.confirm_window is not None and self.confirm_hits > self.confirm_window:
            raise ConfigurationError(f"confirm_hits={self.confirm_hits} exceeds "
                                     f"confirm_window={self.confirm_window}")

    @property
    def confirm_window_frames(self) -> int:
        """Frames within which a track must collect ``confirm_hits`` hits:
        ``confirm_window`` if given, else ``ceil(confirm_window_s /
        frame_period_s)``, at least ``confirm_hits``."""
        if self.confirm_window is not None:
            return int(self.confirm_window)
        n = int(np.ceil(self.confirm_window_s / self.frame_period_s - 1e-9))
        return max(n, int(self.confirm_hits))

    @property
    def confirm_hits_frames(self) -> int:
        """Hits that confirm a tentative track: ``confirm_hits``, or more when
        ``confirm_fraction`` of :attr:`confirm_window_frames` is more (rounded
        up), so that the test is as strict at 20 fps as at 150 ms."""
        n = int(np.ceil(self.confirm_fraction * self.confirm_window_frames - 1e-9))
        return max(int(self.confirm_hits), n)

    @property
    def max_misses_frames(self) -> int:
        """Consecutive misses that delete a confirmed track: ``max_misses`` if
        given, else ``ceil(max_coast_s / frame_period_s)`` (at least 1)."""
        if self.max_misses is not None:
            return int(self.max_misses)
        return max(1, int(np.ceil(self.max_coast_s / self.frame_period_s - 1e-9)))

    @property
    def measurement_covariance(self) -> NDArray:
        return np.diag(np.square(self.measurement_std))

    @property
    def gate_d2(self) -> float:
        return chi2_gate(self.gate_probability, 3)


def track_initial_state(measurement: ArrayLike, config: EkfConfig) -> tuple[NDArray, NDArray]:
    """State and covariance of a new track from one ``(range_m, omega_rad, doppler_mps)``.

    Position: :func:`factors.models.detection_to_local` with its first-order
    covariance (:func:`factors.models.detection_covariance_local`); velocity:
    the Doppler along the line of sight (std of the Doppler) plus a zero-mean
    tangential part (``init_tangential_speed_std_mps``).
    """
    r, om, v = (float(c) for c in measurement)
    sr, so, sv = config.measurement_std
    u = detection_to_local(1.0, om)  # line of sight (unit vector)
    pos = r * u
    t = np.array([-u[1], u[0]])     # across it
    p = np.zeros((4, 4))
    p[:2, :2] = detection_covariance_local(r, om, sr, so)
    p[2:, 2:] = sv**2 * np.outer(u, u) + config.init_tangential_speed_std_mps**2 * np.outer(t, t)
    return np.concatenate([pos, v * u]), symmetrize(p)


def ekf_predict(x: NDArray, p: NDArray, frame_period_s: float, sigma_a_mps2: float):
    """One constant-velocity prediction ``(F x, F P F^T + Q)`` (:mod:`factors.motion`)."""
    f = cv_transition(frame_period_s)
    return f @ x, symmetrize(f @ p @ f.T + cv_process_noise(frame_period_s, sigma_a_mps2))


def wrap_innovation(nu: NDArray, doppler_wrap_mps: float | None = None) -> NDArray:
    """Wrap innovations ``(..., 3)`` in place and return them: the spatial
    frequency into ``[-pi, pi)``, the Doppler into ``[-U, U)`` when
    ``doppler_wrap_mps = U`` is given (modulo twice the unambiguous speed)."""
    nu[..., 1] = wrap_angle(nu[..., 1])
    if doppler_wrap_mps is not None:
        u = float(doppler_wrap_mps)
        nu[..., 2] = (nu[..., 2] + u) % (2.0 * u) - u
    return nu


def _innovation(x: NDArray, p: NDArray, z: NDArray, r: NDArray, doppler_wrap_mps=None):
    h, jac = measurement_model(x, _ZERO_POSE)
    nu = wrap_innovation(z - h, doppler_wrap_mps)
    s = symmetrize(jac @ p @ jac.T + r)
    return nu, jac, s


def ekf_update(x: NDArray, p: NDArray, z: ArrayLike, r: NDArray, *,
               doppler_wrap_mps: float | None = None):
    """EKF update with one measurement ``z (3,)`` and noise ``r (3, 3)``.

    doppler_wrap_mps : wrap the Doppler innovation into ``[-U, U)``
        (:func:`wrap_innovation`; ``EkfConfig.doppler_wrap_mps``).
    Returns ``x (4,), P (4, 4), d2`` (the Mahalanobis distance of the innovation).
    """
    nu, jac, s = _innovation(x, p, np.asarray(z, dtype=float).copy(), r, doppler_wrap_mps)
    # K = P H^T S^-1, computed as (S^-1 H P)^T; numpy for these 3 x 3 solves
    # (scipy's checks and BLAS dispatch cost more than the solve itself, and
    # a multi-threaded BLAS took 35 ms a call on a loaded machine).
    np.linalg.cholesky(s)  # raises LinAlgError when S is not positive definite
    sol = np.linalg.solve(s, np.column_stack([jac @ p, nu]))
    gain = sol[:, :4].T
    d2 = float(nu @ sol[:, 4])
    ikh = np.eye(4) - gain @ jac
    p_new = ikh @ p @ ikh.T + gain @ r @ gain.T
    return x + gain @ nu, symmetrize(p_new), d2


class _Track:
    __slots__ = ("track_id", "x", "p", "hits", "age", "misses", "confirmed")

    def __init__(self, track_id: int, x: NDArray, p: NDArray) -> None:
        self.track_id = track_id
        self.x, self.p = x, p
        self.hits, self.age, self.misses = 1, 1, 0
        self.confirmed = False


class LocalTracker:
    """Multi-target EKF tracker of one node (module docstring).

    ``step(measurements)`` advances one frame and returns the confirmed
    tracks as ``(track_id, state (4,), covariance (4, 4))`` tuples.
    """

    def __init__(self, config: EkfConfig | None = None) -> None:
        self.config = EkfConfig() if config is None else config
        self._tracks: list[_Track] = []
        self._next_id = 0
        self._r = self.config.measurement_covariance
        self._gate = self.config.gate_d2
        self._started = False

    @property
    def tracks(self) -> list[_Track]:
        """All live tracks, tentative ones included (read-only use)."""
        return list(self._tracks)

    def _checked_input(self, measurements: ArrayLike, frame_period_s) -> tuple[NDArray, float]:
        """``(z, T)``: the physical rows of the measurements (range within
        :data:`MAX_RANGE_M`, Doppler within :data:`MAX_SPEED_MPS`; others are
        ignored, as a missed detection) and the time since the last step."""
        z = check_finite(as_float_array(measurements, "measurements"), "measurements")
        if z.ndim != 2 or z.shape[1] != 3:
            raise ValidationError(f"measurements must have shape (K, 3), got {z.shape}")
        if frame_period_s is None:
            t = self.config.frame_period_s
        elif isinstance(frame_period_s, (bool, np.bool_)) or not isinstance(
                frame_period_s, (int, float, np.integer, np.floating)):
            raise ValidationError(f"frame_period_s={frame_period_s!r} must be a number")
        else:
            t = float(check_positive(frame_period_s, "frame_period_s", strict=False))
        physical = (np.abs(z[:, 0]) <= MAX_RANGE_M) & (np.abs(z[:, 2]) <= MAX_SPEED_MPS)
        return z[physical], t

    def _predict_all(self, t: float) -> None:
        """Predict every track over ``t`` s; a track whose prediction is no
        longer finite (a gap of years) is dropped."""
        cfg = self.config
        keep = []
        with np.errstate(over="ignore", invalid="ignore"):
            for tr in self._tracks:
                tr.x, tr.p = ekf_predict(tr.x, tr.p, t, cfg.sigma_a_mps2)
                if np.all(np.isfinite(tr.x)) and np.all(np.isfinite(tr.p)):
                    keep.append(tr)
        self._tracks = keep

    def _costs(self, z: NDArray) -> NDArray:
        """Assignment costs ``d^2 + ln det S`` of every (track, measurement)
        pair inside the gate, ``inf`` outside it."""
        cfg = self.config
        cost = np.full((len(self._tracks), z.shape[0]), np.inf)
        if not z.shape[0]:
            return cost
        for i, tr in enumerate(self._tracks):
            if tr.x[0] ** 2 + tr.x[1] ** 2 < 1e-12:
                continue
            h, jac = measurement_model(tr.x, _ZERO_POSE)
            s = symmetrize(jac @ tr.p @ jac.T + self._r)
            if not np.all(np.isfinite(s)):
                continue
            try:
                chol = np.linalg.cholesky(s)
            except np.linalg.LinAlgError:
                continue
            nu = wrap_innovation(z - h, cfg.doppler_wrap_mps)
            w = np.linalg.solve(chol, nu.T)  # 3 x 3 (numpy: see ekf_update)
            d2 = np.sum(w * w, axis=0)
            ok = d2 < self._gate
            cost[i, ok] = d2[ok] + 2.0 * np.sum(np.log(np.diag(chol)))
        return cost

    def _assign(self, cost: NDArray, rows: NDArray, free: NDArray, z: NDArray,
                assigned_t: NDArray) -> None:
        """Global nearest neighbour of the tracks ``rows`` over the measurements
        still ``free`` (updated in place), and the EKF update of each pair."""
        cols = np.flatnonzero(free)
        if not rows.size or not cols.size:
            return
        sub = cost[np.ix_(rows, cols)]
        finite = np.isfinite(sub)
        if not finite.any():
            return
        ri, ci = linear_sum_assignment(np.where(finite, sub, 1e12))
        for a, b in zip(ri, ci):
            if not finite[a, b]:
                continue
            i, j = int(rows[a]), int(cols[b])
            tr = self._tracks[i]
            tr.x, tr.p, _ = ekf_update(tr.x, tr.p, z[j], self._r,
                                       doppler_wrap_mps=self.config.doppler_wrap_mps)
            tr.hits += 1
            tr.misses = 0
            assigned_t[i] = True
            free[j] = False

    def _births(self, z: NDArray, candidates: NDArray) -> None:
        """A tentative track from each candidate measurement, unless it lies
        in the gate of a track born from another one of this frame (two
        clusters of one body start one track)."""
        born: list[_Track] = []
        for j in np.flatnonzero(candidates):
            if z[j, 0] <= 0:
                continue
            if born:
                saved, self._tracks = self._tracks, born
                near = np.isfinite(self._costs(z[j:j + 1])).any()
                self._tracks = saved
                if near:
                    continue
            x0, p0 = track_initial_state(z[j], self.config)
            born.append(_Track(self._next_id, x0, p0))
            self._next_id += 1
        self._tracks.extend(born)

    def step(self, measurements: ArrayLike, *, frame_period_s: float | None = None):
        """Advance one frame with its measurements ``(K, 3)``; ``frame_period_s``
        is the time since the last step (default ``config.frame_period_s``).
        Rows beyond :data:`MAX_RANGE_M` or :data:`MAX_SPEED_MPS` are ignored."""
        z, t = self._checked_input(measurements, frame_period_s)
        cfg = self.config
        if self._started:
            self._predict_all(t)
        self._started = True
        cost = self._costs(z)
        confirmed = np.array([tr.confirmed for tr in self._tracks], bool)
        free = np.ones(z.shape[0], bool)
        assigned_t = np.zeros(len(self._tracks), bool)
        # Confirmed tracks choose first: a tentative track born from one
        # outlier must not take the next centroid from the walker's track.
        self._assign(cost, np.flatnonzero(confirmed), free, z, assigned_t)
        self._assign(cost, np.flatnonzero(~confirmed), free, z, assigned_t)
        # A centroid inside the gate of a confirmed track, or of a tentative
        # one that had its own centroid this frame, is that target's (a
        # second cluster of the body): it starts no track of its own.
        owners = confirmed | assigned_t
        in_gate = np.isfinite(cost[owners]).any(axis=0) if owners.any() else \
            np.zeros(z.shape[0], bool)
        if confirmed.any() and cfg.body_radius_m > 0 and z.shape[0]:
            # ... and so is one within a body's radius of a confirmed track.
            pos = detection_to_local(z[:, 0], z[:, 1])
            ctr = np.array([tr.x[:2] for tr, c in zip(self._tracks, confirmed) if c])
            dist = np.linalg.norm(pos[:, None, :] - ctr[None], axis=2)
            in_gate |= (dist < cfg.body_radius_m).any(axis=1)
        keep = []
        need = cfg.confirm_hits_frames
        for i, tr in enumerate(self._tracks):
            tr.age += 1
            if not assigned_t[i]:
                tr.misses += 1
            if not tr.confirmed and tr.hits >= need:
                tr.confirmed = True
            if tr.confirmed:
                alive = tr.misses < cfg.max_misses_frames
            else:
                # Can it still reach its hits within the confirmation window?
                alive = tr.hits + (cfg.confirm_window_frames - tr.age) >= need
            if alive:
                keep.append(tr)
        self._tracks = keep
        self._births(z, free & ~in_gate)
        return [(tr.track_id, tr.x.copy(), tr.p.copy()) for tr in self._tracks if tr.confirmed]


def frames_to_step(frames: ArrayLike, config: EkfConfig | None = None) -> NDArray:
    """The frames a tracker steps through for detections at ``frames``: every
    distinct frame, plus the first ``max(max_misses_frames, confirm_window_frames)``
    frames of each gap (prediction-only steps: coasting tracks report and
    then die there, exactly as when stepping every frame of the gap). After
    that no track is alive, so the rest of the gap needs no step: a gap of
    10^12 frames costs a handful of steps, not 10^12.
    Returns a sorted int64 array."""
    cfg = EkfConfig() if config is None else config
    present = np.unique(np.asarray(frames, dtype=np.int64))
    if present.size < 2:
        return present
    pad = max(cfg.max_misses_frames, cfg.confirm_window_frames)
    gaps = frame_steps(present) - 1  # not np.diff: frames at both ends of int64
    extra = np.minimum(gaps, pad)
    fill = np.repeat(present[:-1], extra) + (np.arange(int(extra.sum())) -
                                             np.repeat(np.cumsum(extra) - extra, extra) + 1)
    return np.union1d(present, fill)


def track_centroids(
    centroids: Detections,
    config: EkfConfig | None = None,
    *,
    frames: Sequence[int] | NDArray | None = None,
) -> Tracks:
    """Local-frame tracks from a node's centroids (all frames).

    centroids : :class:`Detections`, one row per centroid per frame.
    frames : the frames to step through (default: :func:`frames_to_step` of
        the centroids' frames: the frames present and, in each gap, the first
        frames while a track can still coast); frames without centroids are
        prediction-only steps, a longer gap one prediction over the time it
        spans.
    Returns the confirmed tracks at every frame they are alive (frames where
    a track coasts without a measurement included).
    """
    cfg = EkfConfig() if config is None else config
    if frames is None:
        if len(centroids) == 0:
            return Tracks.empty()
        frames = frames_to_step(centroids.frame, cfg)
    frames = np.asarray(frames)
    if frames.ndim != 1 or (frames.size and not np.issubdtype(frames.dtype, np.integer)):
        raise ValidationError(f"frames must be a 1-D integer array, got {frames.dtype} "
                              f"{frames.shape}")
    if frames.size > 1 and np.any(frames[1:] <= frames[:-1]):  # no np.diff: int64 may wrap
        raise ValidationError("frames must be strictly increasing")
    tracker = LocalTracker(cfg)
    meas = centroids.measurements
    order = np.argsort(centroids.frame, kind="stable")
    sorted_frames = centroids.frame[order]
    out_f, out_id, out_x, out_p = [], [], [], []
    prev = None
    for f in frames:
        lo = np.searchsorted(sorted_frames, f, side="left")
        hi = np.searchsorted(sorted_frames, f, side="right")  # not f + 1: f may be int64's last
        period = cfg.frame_period_s * (1 if prev is None else int(f) - int(prev))
        for tid, x, p in tracker.step(meas[order[lo:hi]], frame_period_s=period):
            out_f.append(int(f))
            out_id.append(tid)
            out_x.append(x)
            out_p.append(p)
        prev = f
    if not out_f:
        return Tracks.empty()
    return Tracks(frame=np.asarray(out_f), track_id=np.asarray(out_id),
                  state=np.asarray(out_x), covariance=np.asarray(out_p))
