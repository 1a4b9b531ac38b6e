"""Noticing a moved radar: a streaming decalibration monitor (docs/CALIBRATION.md,
"Noticing a moved radar").

Per frame, each monitored node's range and spatial frequency are compared with
the target state fused from the other nodes (leave-one-node-out,
:func:`mmsnap_graph.fusion.solve.solve`); the innovations give per-frame
information and score about the node's pose error (:mod:`.stats`).
Windows of the last 3 to 20 s are tested against the reference (all earlier
data since the last reset, with the calibration covariance as prior) by a
chi-square(3) generalized likelihood ratio ``T``; ``T`` above ``threshold``
is a change. The change frame is the start of the window that maximizes
``T``; the node is then re-calibrated by Gauss-Newton on its pose from
``recalibration_s`` of data after the change, against the other nodes' fused
states, and monitoring restarts with the new pose and its covariance.

With two nodes only the non-reference node is monitored (a move of either
changes the same relative pose, which is the non-reference node's pose in the
reference frame). With three or more every node is, and the global frame
stays that of the nodes that did not move.

:class:`DecalibrationMonitor` works frame by frame (:meth:`~DecalibrationMonitor.update`)
or on many frames at once (:meth:`~DecalibrationMonitor.update_frames`, same
results); :func:`monitor_recording` runs it on a
:class:`~mmsnap_graph.data.recording.Recording`'s centroids.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray
from tqdm import tqdm

from ...data.noise import GaussianPrior, MeasurementNoise, declared_noise
from ...data.recording import Recording
from ...errors import MissingStepError, ValidationError
from ...fusion.frame_problem import FrameProblem
from ...fusion.options import FusionOptions
from ...fusion.solve import solve
from ..._validation import (as_float_array, check_count, check_finite, check_pose, chi2_gate,
                           positive_scalar, short_repr)
from .stats import (
    PoseFit,
    frame_contributions,
    recalibrate_pose,
    suffix_statistics,
    window_statistic,
)

__all__ = ["DEFAULT_THRESHOLD", "DEFAULT_WINDOWS_S", "DEFAULT_POSE_SIGMAS", "ChangePoint",
           "Recalibration", "MonitorUpdate", "DecalibrationMonitor", "MonitorResult",
           "recording_measurements", "monitor_recording"]

#: Per-test false-alarm probability 1e-7 (35.4): with 24,000 frames per hour
#: (150 ms), four window lengths and ten nodes, a Bonferroni bound of 0.1 false
#: alarms per hour when the noise model holds.
DEFAULT_THRESHOLD = chi2_gate(1.0 - 1e-7, 3)
#: Window lengths of the change test, seconds of frames with an observation.
DEFAULT_WINDOWS_S = (3.0, 6.0, 12.0, 20.0)
#: Frames per update_frames call of monitor_recording (the progress bar's step).
_PROGRESS_BLOCK = 100
#: Pose sigmas ``(x_m, y_m, phi_rad)`` assumed for a calibration given without
#: covariance (the reference then learns the pose error from the data).
DEFAULT_POSE_SIGMAS = (0.1, 0.1, np.deg2rad(2.0))
#: The leave-one-out fusion's prior: position free (1 km), the paper's velocity sigma.
_LOO_PRIOR = GaussianPrior(sigmas=np.array([1e3, 1e3, 3.5, 3.5]))


@dataclass(frozen=True, kw_only=True, slots=True)
class ChangePoint:
    """A detected move of ``node``.

    frame, time_s : the estimated first frame (and its time) with the new pose.
    detection_frame, detection_time_s : when ``T`` crossed the threshold.
    statistic : ``T`` at detection; window_frames : the frames of its window.
    offset : (3,) the pose error over the change window (body tangent
    ``(dx_b, dy_b, dphi)``), a first estimate before the re-calibration.
    """

    node: str
    frame: int
    time_s: float
    detection_frame: int
    detection_time_s: float
    statistic: float
    window_frames: int
    offset: NDArray


@dataclass(frozen=True, kw_only=True, slots=True)
class Recalibration:
    """``node``'s new pose from the frames ``first_frame..last_frame`` after ``change``.

    old_pose : (3,) the pose before; fit : the re-estimated pose
    (:class:`~mmsnap_graph.calibration.monitor.stats.PoseFit`: ``pose``,
    ``covariance`` in the body tangent, ``success``, ``message``)."""

    node: str
    change: ChangePoint
    old_pose: NDArray
    fit: PoseFit
    first_frame: int
    last_frame: int
    n_frames: int


@dataclass(frozen=True, kw_only=True, slots=True)
class MonitorUpdate:
    """One frame's outcome: ``statistics`` node -> largest ``T`` over the
    windows (NaN when the node was not tested), any ``change`` detected and
    any ``recalibration`` finished at this frame."""

    frame: int
    time_s: float
    statistics: Mapping[str, float]
    change: ChangePoint | None = None
    recalibration: Recalibration | None = None


@dataclass(slots=True)
class _NodeState:
    """What the monitor keeps for one node."""

    prior_cov: NDArray
    frames: list = field(default_factory=list)
    times: list = field(default_factory=list)
    rows: list = field(default_factory=list)          # (state, covariance, measurement)
    a: list = field(default_factory=list)
    b: list = field(default_factory=list)
    ref_a: NDArray = field(default_factory=lambda: np.zeros((3, 3)))
    ref_b: NDArray = field(default_factory=lambda: np.zeros(3))
    nis_sum: float = 0.0
    n_seen: int = 0
    change: ChangePoint | None = None                  # set while re-calibrating

    def reset(self, prior_cov: NDArray) -> None:
        self.prior_cov = prior_cov
        self.frames, self.times, self.rows, self.a, self.b = [], [], [], [], []
        self.ref_a, self.ref_b = np.zeros((3, 3)), np.zeros(3)
        self.nis_sum, self.n_seen, self.change = 0.0, 0, None

    def _keep(self, keep: list[int]) -> None:
        for name in ("frames", "times", "rows", "a", "b"):
            values = getattr(self, name)
            setattr(self, name, [values[k] for k in keep])

    def drop_from(self, frame: int) -> None:
        """Forget the buffered frames from ``frame`` on."""
        self._keep([k for k, f in enumerate(self.frames) if f < frame])

    def keep_from(self, frame: int) -> None:
        """Forget the buffered frames before ``frame``."""
        self._keep([k for k, f in enumerate(self.frames) if f >= frame])

    @property
    def scale(self) -> float:
        """Noise scale ``s^2``: mean NIS per degree of freedom (floor 0.25)."""
        return max(self.nis_sum / (2.0 * max(self.n_seen, 1)), 0.25)

    def reference(self) -> tuple[NDArray, NDArray]:
        """``(delta_ref, C_ref)`` from the prior and the frames out of the windows."""
        info = np.linalg.inv(self.prior_cov) + self.ref_a / self.scale
        cov = np.linalg.inv(info)
        return cov @ (self.ref_b / self.scale), cov


def _check_poses(node_poses) -> dict[str, NDArray]:
    if not isinstance(node_poses, Mapping) or len(node_poses) < 2:
        raise ValidationError(f"node_poses must map at least two node names to poses, "
                              f"got {node_poses!r}")
    out = {}
    for name, pose in node_poses.items():
        out[str(name)] = check_pose(pose, f"node_poses[{name}]").copy()
    return out


def _check_covariances(names, node_covariances) -> dict[str, NDArray]:
    default = np.diag(np.square(DEFAULT_POSE_SIGMAS))
    out = {n: default.copy() for n in names}
    if node_covariances is not None and not isinstance(node_covariances, Mapping):
        raise ValidationError(f"node_covariances must map node names to (3, 3) covariances, "
                              f"got {short_repr(node_covariances)}")
    for name, cov in dict(node_covariances or {}).items():
        if name not in out:
            raise ValidationError(f"node_covariances[{name!r}]: no such node in node_poses")
        c = as_float_array(cov, f"node_covariances[{name}]")
        if c.shape != (3, 3):
            raise ValidationError(f"node_covariances[{name}] must have shape (3, 3), got {c.shape}")
        # The reference node's zero covariance (it defines the frame) and an
        # unknown (NaN) one are replaced by the default: the node is tested
        # like any other.
        if not np.all(np.isfinite(c)) or not np.any(c):
            continue
        if np.any(np.linalg.eigvalsh(0.5 * (c + c.T)) <= 0):
            raise ValidationError(f"node_covariances[{name}] must be positive definite, "
                                  f"got {c.tolist()}")
        out[name] = 0.5 * (c + c.T)
    return out

#: Longest test window or re-calibration span, in frames (10^7 frames are
#: 17 days at 150 ms: longer ones are unit mistakes, and would overflow).
MAX_SPAN_FRAMES = 1e7


class DecalibrationMonitor:
    """Streaming decalibration monitor (module doc).

    node_poses : name -> (3,) pose, in order (the first is the reference).
    noise : the nodes' measurement noise (the centroid noise, not the radar's
        resolutions: the statistic is whitened by it; a wrong overall scale is
        absorbed by the noise scale, a wrong ratio between range and spatial
        frequency is not).
    node_covariances : name -> (3, 3) calibration covariance (body tangent);
        missing nodes get :data:`DEFAULT_POSE_SIGMAS`.
    frame_period_s : converts ``windows_s`` and ``recalibration_s`` to frames
        and frame numbers to default times.
    threshold : ``T`` above it is a change (:data:`DEFAULT_THRESHOLD`).
    windows_s : window lengths of the test (:data:`DEFAULT_WINDOWS_S`).
    recalibration_s : data after the change used to re-calibrate (seconds of
        observed frames).
    min_frames : frames a node needs after a reset before it is tested.
    """

    def __init__(self, node_poses: Mapping[str, ArrayLike], *,
                 noise: MeasurementNoise = MeasurementNoise(),
                 node_covariances: Mapping[str, ArrayLike] | None = None,
                 frame_period_s: float = 0.15, threshold: float = DEFAULT_THRESHOLD,
                 windows_s: Sequence[float] = DEFAULT_WINDOWS_S, recalibration_s: float = 15.0,
                 min_frames: int = 30) -> None:
        self._poses = _check_poses(node_poses)
        if not isinstance(noise, MeasurementNoise):
            raise ValidationError(f"noise must be a MeasurementNoise, got {noise!r}")
        frame_period_s = positive_scalar(frame_period_s, "frame_period_s")
        threshold = positive_scalar(threshold, "threshold")
        recalibration_s = positive_scalar(recalibration_s, "recalibration_s")
        w = as_float_array(windows_s, "windows_s") if not isinstance(windows_s, str) \
            else np.array(np.nan)
        if w.ndim != 1 or w.size == 0 or not np.all(np.isfinite(w) & (w > 0)):
            raise ValidationError(f"windows_s must be positive lengths in seconds, got "
                                  f"{short_repr(windows_s)}")
        check_count(min_frames, "min_frames")
        for name, value in (("windows_s", float(w.max())), ("recalibration_s", recalibration_s)):
            if value / frame_period_s > MAX_SPAN_FRAMES:
                raise ValidationError(
                    f"{name}={value!r} is {value / frame_period_s:.3g} frames of "
                    f"{frame_period_s:g} s; at most {MAX_SPAN_FRAMES:.0e} frames (a longer "
                    "span than any recording: seconds typed in another unit?)")
        self.noise, self.threshold = noise, float(threshold)
        self.frame_period_s = float(frame_period_s)
        self.node_names = list(self._poses)
        self.monitored = self.node_names if len(self.node_names) >= 3 else self.node_names[1:]
        self._windows = np.unique(np.maximum(1, np.round(w / frame_period_s)).astype(int))
        self._recal_frames = max(3, int(round(recalibration_s / frame_period_s)))
        self._min_frames = int(min_frames)
        covs = _check_covariances(self.node_names, node_covariances)
        self._nodes = {n: _NodeState(prior_cov=covs[n]) for n in self.monitored}
        self._frame = 0
        self.changes: list[ChangePoint] = []
        self.recalibrations: list[Recalibration] = []

    @property
    def poses(self) -> dict[str, NDArray]:
        """The current node poses (re-calibrated ones included)."""
        return {n: p.copy() for n, p in self._poses.items()}

    def recalibrating(self) -> list[str]:
        """Nodes with a detected change whose re-calibration is still collecting data."""
        return [n for n, st in self._nodes.items() if st.change is not None]

    # ------------------------------------------------------------ input
    def _measurement_rows(self, measurements) -> NDArray:
        if isinstance(measurements, Mapping):
            z = np.full((len(self.node_names), 3), np.nan)
            for name, row in measurements.items():
                if name not in self._poses:
                    raise ValidationError(f"measurements[{name!r}]: no such node")
                if row is None:
                    continue
                r = as_float_array(row, f"measurements[{name!r}]")
                if r.shape != (3,):
                    raise ValidationError(f"measurements[{name!r}] must be one row (range_m, "
                                          f"omega_rad, doppler_mps), got {short_repr(row)}")
                z[self.node_names.index(name)] = r
            return z[None]
        z = as_float_array(measurements, "measurements")
        return z

    def _check_frames(self, measurements, times_s) -> tuple[NDArray, NDArray]:
        z = self._measurement_rows(measurements)
        n = len(self.node_names)
        if z.ndim != 3 or z.shape[1:] != (n, 3):
            raise ValidationError(f"measurements must have shape (F, {n}, 3) (one row per node "
                                  f"in {self.node_names}), got {z.shape}")
        seen = np.all(np.isfinite(z), axis=2)
        bad = seen & ((z[..., 0] <= 0) | (np.abs(z[..., 1]) > np.pi + 1e-9))
        if np.any(bad):
            f, i = np.argwhere(bad)[0]
            raise ValidationError(f"measurements[{f}, {self.node_names[i]}]={z[f, i].tolist()} "
                                  f"needs range > 0 and |omega| <= pi")
        z = np.where(seen[..., None], z, np.nan)
        if times_s is None:
            times = (self._frame + np.arange(z.shape[0])) * self.frame_period_s
        else:
            times = check_finite(as_float_array(times_s, "times_s"), "times_s").reshape(-1)
            if times.shape != (z.shape[0],):
                raise ValidationError(f"times_s must have shape ({z.shape[0]},), got {times.shape}")
        return z, times

    # ------------------------------------------------------------ fusion
    def _fuse(self, z: NDArray) -> tuple[NDArray, NDArray, NDArray]:
        """Leave-one-out states ``(F, N, 4)``, covariances ``(F, N, 4, 4)`` and
        ``ok (F, N)`` for the monitored nodes; nodes being re-calibrated are
        left out of the other nodes' fusion."""
        f, n = z.shape[:2]
        seen = np.all(np.isfinite(z), axis=2)
        excluded = np.array([self._nodes.get(m) is not None and self._nodes[m].change is not None
                             for m in self.node_names])
        states, covs = np.full((f, n, 4), np.nan), np.full((f, n, 4, 4), np.nan)
        ok = np.zeros((f, n), bool)
        rows, obs, where = [], [], []
        for name in self.monitored:
            i = self.node_names.index(name)
            others = seen & ~excluded[None, :]
            others[:, i] = False
            use = seen[:, i] & others.any(axis=1)
            rows.append(np.flatnonzero(use))
            obs.append(others[use])
            where.append(np.full(int(use.sum()), i))
        frames = np.concatenate(rows)
        if frames.size == 0:
            return states, covs, ok
        node = np.concatenate(where)
        zz = np.nan_to_num(z[frames], nan=1.0)
        problem = FrameProblem(poses=np.stack([self._poses[m] for m in self.node_names]),
                               measurements=zz, observed=np.concatenate(obs), noise=self.noise,
                               prior=_LOO_PRIOR)
        res = solve(problem, FusionOptions(solver="vectorized"))
        states[frames, node], covs[frames, node] = res.state, res.covariance
        ok[frames, node] = res.success
        return states, covs, ok

    # ------------------------------------------------------------ updates
    def update(self, measurements, time_s: float | None = None) -> MonitorUpdate:
        """One frame: ``measurements`` is ``(N, 3)`` in node order (an all-NaN
        row = not seen) or a mapping name -> ``(3,)`` / None."""
        z = self._measurement_rows(measurements)
        if z.ndim == 2:
            z = z[None]
        return self.update_frames(z, None if time_s is None else [time_s])[0]

    def update_frames(self, measurements: ArrayLike, times_s: ArrayLike | None = None
                      ) -> list[MonitorUpdate]:
        """Many frames ``(F, N, 3)`` at once: one fusion call for all of them,
        repeated from the frame after any change or re-calibration; the same
        results as :meth:`update` frame by frame."""
        z, times = self._check_frames(measurements, times_s)
        out: list[MonitorUpdate] = []
        start = 0
        while start < z.shape[0]:
            states, covs, ok = self._fuse(z[start:])
            for k in range(start, z.shape[0]):
                j = k - start
                upd = self._step(z[k], float(times[k]), states[j], covs[j], ok[j])
                out.append(upd)
                if upd.change is not None or upd.recalibration is not None:
                    break
            start = k + 1
        return out

    def _step(self, z, time_s, states, covs, ok) -> MonitorUpdate:
        frame = self._frame
        self._frame += 1
        stats = {n: float("nan") for n in self.monitored}
        for name in self.monitored:
            i = self.node_names.index(name)
            if ok[i]:
                stats[name] = self._ingest(name, frame, time_s, states[i], covs[i], z[i])
        change = None
        alarms = [n for n, t in stats.items() if np.isfinite(t) and t >= self.threshold]
        if alarms:
            change = self._declare(max(alarms, key=lambda n: stats[n]), frame, time_s,
                                   stats)
        recal = None
        for name, st in self._nodes.items():
            if st.change is not None and len(st.frames) >= self._recal_frames:
                recal = self._recalibrate(name)
                break
        return MonitorUpdate(frame=frame, time_s=time_s, statistics=stats, change=change,
                             recalibration=recal)

    def _ingest(self, name, frame, time_s, state, cov, z) -> float:
        st = self._nodes[name]
        fc = frame_contributions(self._poses[name], state[None], cov[None], z[None], self.noise)
        st.frames.append(frame)
        st.times.append(time_s)
        st.rows.append((state, cov, z))
        st.a.append(fc.a[0])
        st.b.append(fc.b[0])
        if st.change is not None:
            return float("nan")
        st.nis_sum += float(fc.nis[0])
        st.n_seen += 1
        while len(st.frames) > self._windows[-1]:
            st.ref_a += st.a.pop(0)
            st.ref_b += st.b.pop(0)
            for lst in (st.frames, st.times, st.rows):
                lst.pop(0)
        if st.n_seen < self._min_frames:
            return float("nan")
        delta_ref, cov_ref = st.reference()
        t = window_statistic(np.array(st.a), np.array(st.b), self._windows, delta_ref, cov_ref,
                             st.scale)
        return float(np.max(t))

    def _declare(self, name, frame, time_s, stats) -> ChangePoint:
        st = self._nodes[name]
        a, b = np.array(st.a), np.array(st.b)
        delta_ref, cov_ref = st.reference()
        k = int(np.argmax(suffix_statistics(a, b, delta_ref, cov_ref, st.scale)))
        offset = np.linalg.pinv(a[k:].sum(axis=0), hermitian=True) @ b[k:].sum(axis=0)
        cp = ChangePoint(node=name, frame=int(st.frames[k]), time_s=float(st.times[k]),
                         detection_frame=frame, detection_time_s=time_s,
                         statistic=float(stats[name]), window_frames=len(st.frames) - k,
                         offset=offset)
        st.change = cp
        st.keep_from(cp.frame)
        for other, ost in self._nodes.items():
            if other != name:
                ost.drop_from(cp.frame)
        self.changes.append(cp)
        return cp

    def _recalibrate(self, name) -> Recalibration:
        st = self._nodes[name]
        states = np.array([r[0] for r in st.rows])
        covs = np.array([r[1] for r in st.rows])
        z = np.array([r[2] for r in st.rows])
        old = self._poses[name].copy()
        fit = recalibrate_pose(old, states, covs, z, self.noise, scale=st.scale)
        rc = Recalibration(node=name, change=st.change, old_pose=old, fit=fit,
                           first_frame=int(st.frames[0]), last_frame=int(st.frames[-1]),
                           n_frames=len(st.frames))
        if fit.success:
            self._poses[name] = fit.pose.copy()
            st.reset(fit.covariance)
        else:
            st.reset(st.prior_cov)
        self.recalibrations.append(rc)
        return rc


# ---------------------------------------------------------------- recordings
@dataclass(frozen=True, kw_only=True, slots=True)
class MonitorResult:
    """The monitor run over a whole recording.

    node_names : node order; frame, time_s : (F,) the frames monitored;
    statistics : (F, N) largest ``T`` per frame and node (NaN: not tested);
    threshold; changes, recalibrations : in time order; initial_poses, poses :
    the poses at the start and at the end (re-calibrated nodes moved);
    noise : the measurement noise used.
    """

    node_names: tuple[str, ...]
    frame: NDArray
    time_s: NDArray
    statistics: NDArray
    threshold: float
    changes: tuple[ChangePoint, ...]
    recalibrations: tuple[Recalibration, ...]
    initial_poses: Mapping[str, NDArray]
    poses: Mapping[str, NDArray]
    noise: MeasurementNoise


def recording_measurements(recording: Recording) -> tuple[NDArray, NDArray]:
    """``(frame (F,), measurements (F, N, 3))`` from the nodes' centroids, frames
    ``0..last``; a node with no centroid, or several (several people), at a
    frame has an all-NaN row there (the monitor follows one target)."""
    names = recording.node_names
    last = -1
    for name in names:
        c = recording.nodes[name].centroids
        if c is not None and len(c):
            last = max(last, int(c.frame.max()))
    frames = np.arange(last + 1)
    z = np.full((frames.size, len(names), 3), np.nan)
    for i, name in enumerate(names):
        c = recording.nodes[name].centroids
        if c is None or not len(c):
            continue
        ok = c.frame >= 0
        counts = np.bincount(c.frame[ok], minlength=frames.size)
        single = ok & (counts[np.clip(c.frame, 0, None)] == 1)
        z[c.frame[single], i] = c.measurements[single]
    return frames, z


def monitor_recording(recording: Recording, *, node_poses: Mapping[str, ArrayLike] | None = None,
                      node_covariances: Mapping[str, ArrayLike] | None = None,
                      noise: MeasurementNoise | None = None, progress: bool = False,
                      **options) -> MonitorResult:
    """Run :class:`DecalibrationMonitor` over ``recording``'s centroids.

    node_poses : default the recording's node poses (its calibration);
        :class:`~mmsnap_graph.errors.MissingStepError` (a
        CalibrationError) when a node has none.
    noise : default the centroid noise the recording declares
        (:func:`~mmsnap_graph.data.noise.declared_noise`, a simulator's),
        else the paper's resolutions.
    progress : a tqdm bar over the frames on stderr.
    options : the monitor's (``threshold``, ``windows_s``, ...);
        ``frame_period_s`` is the recording's.
    """
    if not isinstance(recording, Recording):
        raise ValidationError(f"recording must be a Recording, got {type(recording).__name__}")
    if node_poses is None:
        missing = [n for n, p in recording.node_poses().items() if p is None]
        if missing:
            raise MissingStepError(f"nodes {missing} have no pose: calibrate the recording "
                                   f"first or pass node_poses", step="calibrate",
                                   what=f"nodes {missing} have no pose")
        node_poses = recording.node_poses()
    if noise is None:
        noise = declared_noise(recording.metadata) or MeasurementNoise()
    mon = DecalibrationMonitor(node_poses, noise=noise, node_covariances=node_covariances,
                               frame_period_s=recording.frame_period_s, **options)
    frames, z = recording_measurements(recording)
    initial = mon.poses
    times = frames * recording.frame_period_s
    updates = []
    # In blocks of frames, for the bar: update_frames gives the same results
    # whatever the blocks (it equals update() frame by frame).
    with tqdm(total=frames.size, desc="monitor", unit="frame", disable=not progress) as bar:
        for a in range(0, frames.size, _PROGRESS_BLOCK):
            b = min(a + _PROGRESS_BLOCK, frames.size)
            updates.extend(mon.update_frames(z[a:b], times[a:b]))
            bar.update(b - a)
    stats = np.full((frames.size, len(mon.node_names)), np.nan)
    for k, u in enumerate(updates):
        for name, t in u.statistics.items():
            stats[k, mon.node_names.index(name)] = t
    return MonitorResult(node_names=tuple(mon.node_names), frame=frames,
                         time_s=frames * recording.frame_period_s, statistics=stats,
                         threshold=mon.threshold, changes=tuple(mon.changes),
                         recalibrations=tuple(mon.recalibrations), initial_poses=initial,
                         poses=mon.poses, noise=noise)
