"""Online fusion: one frame at a time from N radars (docs/STREAMING.md).

:class:`FrameStream` takes each frame as it arrives (every node's detections
``(range_m, omega_rad, doppler_mps)`` and a time stamp in seconds) and returns
a :class:`StreamUpdate`: the frame's fused targets with their covariances and
the central tracker's tracks after the update. Per frame it does what
:func:`mmsnap_graph.fusion.recording.sequence.fuse_recording` does for that frame (the
grouping of :func:`mmsnap_graph.fusion.association.associate_frame`, then
one-shot fusion of each group), and what
:func:`mmsnap_graph.tracking.central.track_fused` does (one
:meth:`~mmsnap_graph.tracking.central.CentralTracker.step` with the frame's
successful estimates; a MAP estimate has its prior removed by the tracker).

It is built for latency (docs/validation/speed.md, "Latency"): the grouping is
:class:`~mmsnap_graph.fusion.stream.association.StreamAssociator` (the
decisions of ``associate_frame`` in plain floats for up to four detections
per node, ``associate_frame`` itself otherwise); the default solver
``"scalar"`` is :mod:`mmsnap_graph.fusion.solvers.scalar` (the problem
GTSAM solves, in plain floats, equal to it to the tolerance stated there),
``"gtsam"`` the reference and ``"vectorized"`` numpy's, each through
:func:`mmsnap_graph.fusion.solve.robust_solve`. Each frame is validated once,
with checks on plain floats.

State is bounded: the node poses and settings, the time of the last good
frame, three counters and the tracker's live tracks (each deleted after
``max_misses`` frames without an estimate). Nothing grows with the number of
frames.

Detections per node per frame are capped (``max_detections_per_node``,
default :data:`MAX_DETECTIONS_PER_NODE`): the grouping's assignment grows
as K^2.4 with K detections per node (1,000: 1.5 s; 5,000: 74 s), so a node's
rows beyond the cap, in the order given, are left out of that frame, counted
in ``StreamUpdate.dropped_detections`` and named in its message.

A clock restart (a source whose time goes back, e.g. a radar rebooted) does
not lock the stream: a stamp not after the last good frame's, or more than
:data:`MAX_TIME_JUMP_S` past it, is rejected; when
:data:`CLOCK_RESTART_FRAMES` such frames in a row have stamps that advance
among themselves (each step at most ``MAX_TIME_JUMP_S``), the source's clock
is taken to have restarted: the stream starts over from the last of them (its
tracks end, ``clock_restarts`` counts it, the message says so) and fuses it.

A bad frame (a time stamp that is not finite or not after the previous one,
an unknown node, a detection array of the wrong shape, non-finite values, a
negative range or ``|omega| > pi``) is flagged (``ok`` False, a message) and
skipped: no fusion and no tracker step; the stream goes on with the next
frame. A frame whose association or fusion fails numerically is flagged too,
and the tracker predicts over it (no estimates); so is a frame whose tracker
update fails. A group that cannot be fused is flagged by its status, as in
``fuse_recording``.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections import deque
from concurrent.futures import Executor
from dataclasses import dataclass
from typing import Iterator, Literal, Mapping, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..config import DEFAULT_CONFIG, FusionConfig
from ..options import FusionOptions, NetworkCalibration
from ..recording.pipeline import FusionNetwork
from ..recording.regroup import merge_body_detections
from .association import StreamAssociator
from .checks import StreamPipeline
from ..problem import check_node_noise, check_pose_covariances
from ...data.noise import MeasurementNoise
from ...data.recording import Recording
from ...data.results import Status
from ...errors import MmsnapError, ValidationError
from ...tracking.central import CentralConfig, CentralTracker
from ..._validation import as_float_array, check_count, check_finite, check_heading

__all__ = ["StreamUpdate", "FrameStream", "recording_frames", "sends_empty_frame", "STREAM_CONFIG"]

#: The stream's default configuration: :data:`~mmsnap_graph.fusion.config.DEFAULT_CONFIG`
#: (every check) with the scalar solver (latency; without a robust fit: with
#: one the vectorized solver's, which has it).
STREAM_CONFIG = dataclasses.replace(DEFAULT_CONFIG, solve=FusionOptions(solver="scalar"))

# Failures of one frame's association, fusion or tracker step (numerical ones,
# e.g. a singular covariance of a degenerate detection) that flag the frame.
#: Largest step (s) between the time stamps of two good frames: a stamp
#: further ahead is taken as a bad stamp (1e308, milliseconds as seconds)
#: and its frame rejected, not as the stream's new time.
MAX_TIME_JUMP_S = 86400.0
#: Consecutive rejected frames with self-consistent stamps that restart the
#: stream's clock (module docstring).
CLOCK_RESTART_FRAMES = 3
#: Default cap on one node's detections in one frame (about 0.25 s of
#: grouping on 2 nodes at the cap; module docstring).
MAX_DETECTIONS_PER_NODE = 256

_FRAME_FAILURES = (MmsnapError, np.linalg.LinAlgError, FloatingPointError, ZeroDivisionError,
                   OverflowError, ValueError)

_EMPTY_I8 = np.zeros(0, dtype=np.int8)


@dataclass(frozen=True, kw_only=True, slots=True)
class StreamUpdate:
    """What :meth:`FrameStream.push` returns for one frame.

    index : 0-based count of frames pushed (bad ones included).
    time_s : the frame's time stamp (as given; NaN if it was not a number).
    ok : False for a bad frame (skipped) or a failed association, fusion or
        tracker update; ``message`` says why.
    state, covariance : (G, 4), (G, 4, 4) fused targets of the frame (NaN where a
        group failed); G = 0 for a bad frame.
    status : (G,) int8 :class:`~mmsnap_graph.data.results.Status` codes; success is ``Status.OK``.
    members : (G, N) int, each node's detection row in each group (its row in
        the frame's detections as given), -1 where none.
    degeneracy : (G,) velocity degeneracy of each group.
    rejected : (G, N) bool, the nodes the robust fit or the checks left out.
    track_id, track_state, track_covariance : (T,), (T, 4), (T, 4, 4) the live
        tracks after this frame's update (unchanged by a bad frame).
    latency_s : wall-clock time spent in :meth:`FrameStream.push`.
    dropped_detections : rows left out by the cap ``max_detections_per_node``.
    person_id : (G,) the track each group updated or started (-1: none), as
        ``/fused``'s ``track_id``; final_cost : (G,) each group's final cost
        (the covariance self-check's inputs,
        :meth:`~mmsnap_graph.fusion.recording.consistency.ConsistencyMonitor.add_update`).
    """

    index: int
    time_s: float
    ok: bool
    message: str
    state: NDArray
    covariance: NDArray
    status: NDArray
    members: NDArray
    degeneracy: NDArray
    track_id: NDArray
    track_state: NDArray
    track_covariance: NDArray
    latency_s: float
    rejected: NDArray
    dropped_detections: int = 0
    person_id: NDArray | None = None
    final_cost: NDArray | None = None

    @property
    def success(self) -> NDArray:
        """(G,) bool, the groups fused successfully."""
        return self.status == Status.OK

    def __len__(self) -> int:
        return int(self.state.shape[0])


class FrameStream:
    """Fuse and track frame by frame.

    Parameters
    ----------
    node_names : sequence of N str
        The nodes, in the order of ``node_poses``.
    node_poses : (N, 3) float
        Calibrated poses ``(x_m, y_m, phi_rad)`` in the global frame.
    noise : MeasurementNoise, sequence of N MeasurementNoise or mapping
        Measurement sigmas (default the paper's): one for every node, one per
        node in the order of ``node_names``, or ``{node name: MeasurementNoise}``
        holding every node (docs/CONVENTIONS.md, "Per-node noise").
    config : FusionConfig
        The one pipeline's configuration (:class:`~mmsnap_graph.fusion.config.FusionConfig`,
        default :data:`STREAM_CONFIG`: every check, the scalar solver): the
        association, the solve (``"scalar"``: the problem GTSAM solves, in
        plain floats, per group; ``"gtsam"``: GTSAM; ``"vectorized"``: numpy
        on the frame's groups; the robust fit around any of them), the prior (None: ML), the robust fit and the checks, run as
        :mod:`~mmsnap_graph.fusion.stream.checks` says.
    tracker : CentralConfig or None
        The central tracker's settings (default ``CentralConfig()``); its
        ``frame_period_s`` numbers the frames for the checks (the frame
        periods since the first stamp, rounded) and steps the tracker over
        the first frame; afterwards the tracker's steps come from the stamps.
    pose_covariances : (N, 3, 3) or mapping name -> (3, 3), optional
        Calibration-aware fusion (docs/CONVENTIONS.md): each pose's covariance
        in the Pose2 body tangent (all NaN, all zero or a node left out of the
        mapping: an exact pose); the fused covariances include them.
    range_offset_m : float, optional
        The calibration's range offset (reflection depth, m), added to every
        range first, as the recording drivers add it.
    delay_frames : int
        Frames a frame waits for those after it before it is decided (0: at
        once, from past frames only; :meth:`feed` and :meth:`flush` when > 0).
        With the configuration's ``context_frames`` the checks see what the
        recording drivers see.
    max_detections_per_node : int
        Rows of one node kept per frame (default
        :data:`MAX_DETECTIONS_PER_NODE`, at most 4096); the rest are dropped
        and counted (module docstring).
    wall_executor : concurrent.futures.Executor, optional
        Where the learned walls are learned again (default: in line). The
        walls learned at a decided frame apply
        :attr:`~mmsnap_graph.fusion.config.LearnedWalls.apply_after_frames`
        decided frames later wherever they are learned (the stream waits
        for them then), so an executor (one worker process at low priority,
        as ``mmsnap live`` gives) takes the learning off the frames' path
        without changing a row. The stream does not shut it down.

    Example
    -------
    >>> stream = FrameStream(["S1", "S2"], poses)                      # doctest: +SKIP
    >>> update = stream.push(0.15, {"S1": [[3.1, 0.2, -0.4]], "S2": [[4.0, -0.1, 0.3]]})
    """

    def __init__(self, node_names: Sequence[str], node_poses: ArrayLike, *,
                 config: FusionConfig = STREAM_CONFIG,
                 noise: MeasurementNoise = MeasurementNoise(),
                 tracker: CentralConfig | None = None,
                 pose_covariances: ArrayLike | Mapping[str, ArrayLike] | None = None,
                 range_offset_m: float | None = None,
                 delay_frames: int = 0,
                 max_detections_per_node: int = MAX_DETECTIONS_PER_NODE,
                 wall_executor: Executor | None = None) -> None:
        names = tuple(node_names)
        if not names or not all(isinstance(n, str) for n in names) or len(set(names)) != len(names):
            raise ValidationError(f"node_names must be distinct strings, got {node_names!r}")
        poses = check_finite(as_float_array(node_poses, "node_poses"), "node_poses")
        if poses.shape != (len(names), 3):
            raise ValidationError(f"node_poses must have shape ({len(names)}, 3), got {poses.shape}")
        for i in range(len(names)):
            check_heading(float(poses[i, 2]), f"node_poses[{i}]")
        self.max_detections_per_node = check_count(max_detections_per_node,
                                                   "max_detections_per_node", 1, 4096)
        if not isinstance(config, FusionConfig):
            raise ValidationError(f"config must be a FusionConfig, got {type(config).__name__}")
        if config.solve.covariance != "laplace":
            raise ValidationError("config.solve.covariance must be 'laplace' for a stream (the "
                                  "grid covariance is for recordings)")
        if config.association.source != "centroids" and range_offset_m is not None:
            raise ValidationError("range_offset_m moves centroids' ranges: use source='centroids'")
        if tracker is not None and not isinstance(tracker, CentralConfig):
            raise ValidationError(f"tracker must be a CentralConfig, got {type(tracker).__name__}")
        self.delay_frames = check_count(delay_frames, "delay_frames", 0)
        self.range_offset_m = NetworkCalibration(range_offset_m=range_offset_m).range_offset_m
        self.node_names = names
        self.node_poses = poses
        poses.setflags(write=False)
        noises = check_node_noise(noise, len(names), names)
        # The given noise, or the N per-node ones in node order (a tuple).
        self.noise = noises[0] if isinstance(noise, MeasurementNoise) else noises
        self.pose_covariances = check_pose_covariances(pose_covariances, len(names), names)
        self.config = config
        self.prior = config.prior
        self.solver = config.solve.solver
        self.gate_probability = config.association.gate_probability
        tracker_cfg = CentralConfig() if tracker is None else tracker
        self.frame_period_s = float(tracker_cfg.frame_period_s)
        net = FusionNetwork.make(names, poses, noises, self.pose_covariances, self.prior,
                                 self.frame_period_s)
        self._associator = StreamAssociator(poses, noises, self.gate_probability)
        if wall_executor is not None and not isinstance(wall_executor, Executor):
            raise ValidationError("wall_executor must be a concurrent.futures.Executor, got "
                                  f"{type(wall_executor).__name__}")
        self._pipeline = StreamPipeline(net, config, self.delay_frames, wall_executor)
        self._index = {name: i for i, name in enumerate(names)}
        prior = self.prior
        self._new_tracker = lambda: CentralTracker(
            tracker_cfg, prior_mean=None if prior is None else prior.mean,
            prior_sigmas=None if prior is None else prior.sigmas)
        self._tracker = self._new_tracker()
        self._last_time_s: float | None = None
        self._rejected_times: list[float] = []
        self._first_time_s: float | None = None
        self._last_frame: int | None = None
        self._waiting: deque = deque()
        self._last_decided_s: float | None = None
        self.clock_restarts = 0
        self.frames = 0
        self.bad_frames = 0
        self.failed_groups = 0

    # ------------------------------------------------------------------
    @property
    def tracker_config(self) -> CentralConfig:
        return self._tracker.config

    @property
    def n_tracks(self) -> int:
        """Live tracks of the central tracker."""
        return len(self._tracker.tracks)

    def set_poses(self, node_poses: ArrayLike,
                  pose_covariances: ArrayLike | Mapping[str, ArrayLike] | None = None) -> None:
        """New node poses (N, 3) and their covariances (as the constructor
        takes them) for the frames pushed from now on: a calibration refined
        while the stream runs (``mmsnap live --refine``). The tracks, the
        checks' history and the learned walls are kept; frames already
        solved and held for a look-ahead keep the poses they were solved with."""
        names = self.node_names
        poses = check_finite(as_float_array(node_poses, "node_poses"), "node_poses").copy()
        if poses.shape != (len(names), 3):
            raise ValidationError(f"node_poses must have shape ({len(names)}, 3), got {poses.shape}")
        for i in range(len(names)):
            check_heading(float(poses[i, 2]), f"node_poses[{i}]")
        covs = check_pose_covariances(pose_covariances, len(names), names)
        noises = check_node_noise(self.noise, len(names), names)
        net = FusionNetwork.make(names, poses, noises, covs, self.prior, self.frame_period_s)
        poses.setflags(write=False)
        self.node_poses, self.pose_covariances = poses, covs
        self._associator = StreamAssociator(poses, noises, self.gate_probability)
        self._pipeline.net = net

    def push(self, time_s: float, detections: Mapping[str, ArrayLike] | Sequence[ArrayLike]
             ) -> StreamUpdate:
        """One frame, decided at once (``delay_frames=0``): validate,
        associate, fuse, check, track (:meth:`feed`).

        time_s : the frame's time stamp in seconds (e.g. the host's time of
            arrival), after the previous good frame's.
        detections : ``{node_name: (K, 3) array}`` (a node left out has no
            detections) or a sequence of N arrays in node order; rows are
            ``(range_m, omega_rad, doppler_mps)``.
        Never raises for a bad frame: it returns ``ok=False`` with a message.
        """
        if self.delay_frames:
            raise ValidationError(f"push decides a frame at once; with delay_frames="
                                  f"{self.delay_frames} use feed() and flush()")
        return self.feed(time_s, detections)[0]

    def feed(self, time_s: float, detections: Mapping[str, ArrayLike] | Sequence[ArrayLike]
             ) -> list[StreamUpdate]:
        """One frame (as :meth:`push`); returns the frames decided now, in
        order: this one with ``delay_frames=0``, else those ``delay_frames``
        frames old or more (a bad frame is returned at once; it is not fused)."""
        start = time.perf_counter()
        index = self.frames
        self.frames += 1
        t, per_node, problem = self._validate(time_s, detections)
        note = ""
        if problem is not None and per_node is not None and self._clock_restarted(t):
            note, problem = f"{problem}; the source's clock restarted: the stream starts over", None
            decided = self.flush()
        else:
            decided = []
        if problem is not None:
            self.bad_frames += 1
            return decided + [self._update(index, t, False, problem, None, start)]
        self._rejected_times.clear()
        per_node, dropped, cap_note = self._capped(per_node)
        note = "; ".join(x for x in (note, cap_note) if x)
        self._last_time_s = t
        frame = self._frame_number(t)
        self._pipeline.see(per_node)
        try:
            per_node, kept = self._calibrated(per_node)
            members = self._associator.members(per_node)
            self._pipeline.solve(frame, members, _measurements(per_node, members))
            members = _rows_of(members, kept)
            problem = None
        except _FRAME_FAILURES as exc:
            members, problem = None, f"fusion failed: {type(exc).__name__}: {exc}"
        self._waiting.append((index, t, frame, members, problem, note, dropped, start))
        return decided + self._decide(frame - self.delay_frames)

    def flush(self) -> list[StreamUpdate]:
        """Decide every frame still waiting for its look-ahead (the end of a
        recording or a source), with the frames there are."""
        return self._decide(None)

    def _frame_number(self, t: float) -> int:
        """The frame of a stamp: the frame periods since the first frame's
        (rounded; always after the previous frame's)."""
        if self._first_time_s is None:
            self._first_time_s = t
        k = (t - self._first_time_s) / self.frame_period_s
        if not (math.isfinite(k) and abs(k) < 2.0 ** 52):
            # Stamps that far apart share no check: number anew from this one.
            self._first_time_s, self._last_frame, k = t, None, 0.0
        k = int(round(k))
        if self._last_frame is not None and k <= self._last_frame:
            k = self._last_frame + 1
        self._last_frame = k
        return k

    def _calibrated(self, per_node):
        """The range offset added and one body's centroids merged
        (``config.association.merge_body_m``); the rows kept of each node."""
        merge = self.config.association.merge_body_m
        if merge is None and self.range_offset_m is None:
            return per_node, None
        out, kept = [], []
        for z in per_node:
            if self.range_offset_m is not None and len(z):
                z = z.copy()
                z[:, 0] += self.range_offset_m
            keep = None
            if merge is not None and len(z) > 1:
                keep, merged = merge_body_detections(np.zeros(len(z), np.int64), z, merge)
                keep = np.flatnonzero(keep)
                z = merged[keep]
            out.append(z)
            kept.append(keep)
        return out, kept

    def _decide(self, up_to: int | None) -> list[StreamUpdate]:
        """The updates of the waiting frames up to frame ``up_to`` (None: all)."""
        done = []
        while self._waiting and (up_to is None or self._waiting[0][2] <= up_to):
            index, t, frame, members, problem, note, dropped, start = self._waiting.popleft()
            dt = None if self._last_decided_s is None else t - self._last_decided_s
            self._last_decided_s = t
            if problem is None:
                try:
                    seq = self._pipeline.decide(frame)
                except _FRAME_FAILURES as exc:
                    problem = f"fusion failed: {type(exc).__name__}: {exc}"
            if problem is not None:
                self._step_tracker(np.zeros((0, 4)), np.zeros((0, 4, 4)), dt)
                done.append(self._update(index, t, False, problem, None, start, dropped))
                continue
            ok = seq.status == _OK
            self.failed_groups += int(np.count_nonzero(~ok))
            problem = self._step_tracker(seq.state[ok], seq.covariance[ok], dt)
            message = "; ".join(x for x in (problem, note) if x)
            fused = (seq.state, seq.covariance, np.asarray(seq.status, dtype=np.int8),
                     seq.degeneracy, members, seq.rejected)
            person = None
            if problem is None:
                person = np.full(len(ok), -1, dtype=np.int64)
                person[ok] = self._tracker.estimate_ids
            done.append(self._update(index, t, problem is None, message, fused, start, dropped,
                                     person_id=person, final_cost=seq.final_cost))
        return done

    def _clock_restarted(self, t: float) -> bool:
        """Whether the frame at ``t``, rejected for its stamp alone, is the
        :data:`CLOCK_RESTART_FRAMES`-th in a row of advancing stamps: then
        the stream starts over (tracks ended, clock unset)."""
        prev = self._rejected_times[-1] if self._rejected_times else None
        if prev is not None and prev < t <= prev + MAX_TIME_JUMP_S:
            self._rejected_times.append(t)
        else:
            self._rejected_times[:] = [t]
        if len(self._rejected_times) < CLOCK_RESTART_FRAMES:
            return False
        self._rejected_times.clear()
        self._tracker = self._new_tracker()
        self._last_time_s = None
        self._first_time_s = None
        self.clock_restarts += 1
        return True

    def _capped(self, per_node):
        """``per_node`` with each node's rows cut at ``max_detections_per_node``,
        the number dropped and a note naming the nodes."""
        cap = self.max_detections_per_node
        over = [(i, len(z)) for i, z in enumerate(per_node) if len(z) > cap]
        if not over:
            return per_node, 0, ""
        dropped = sum(k - cap for _, k in over)
        names = ", ".join(f"{self.node_names[i]} ({k})" for i, k in over)
        per_node = [z[:cap] for z in per_node]
        return per_node, dropped, (f"{dropped} detection(s) beyond max_detections_per_node={cap} "
                                   f"left out: {names}")

    def _step_tracker(self, states, covariances, dt) -> str | None:
        """One tracker step; a numerical failure is returned as a message."""
        try:
            self._tracker.update(states, covariances, dt)
        except _FRAME_FAILURES as exc:
            return f"tracker update failed: {type(exc).__name__}: {exc}"
        return None

    # ------------------------------------------------------------------
    def _validate(self, time_s, detections):
        """``(time, per-node (K_n, 3) arrays, problem message or None)``; the
        arrays are given (not None) with a problem when the frame's time
        stamp alone is out of order (a clock restart may follow)."""
        try:
            t = float(time_s)
        except (TypeError, ValueError):
            return math.nan, None, f"time stamp {time_s!r} is not a number"
        if not math.isfinite(t):
            return t, None, f"time stamp {time_s!r} is not finite"
        t, per_node, problem = self._validate_rows(t, detections)
        if problem is not None or self._last_time_s is None:
            return t, per_node, problem
        if not t > self._last_time_s:
            return t, per_node, (f"time stamp {t!r} s is not after the previous frame's "
                                 f"{self._last_time_s!r} s")
        if t - self._last_time_s > MAX_TIME_JUMP_S:
            # Taking it would reject every later frame as "not after" it.
            return t, per_node, (f"time stamp {t!r} s jumps {t - self._last_time_s:.3g} s past "
                                 f"the previous frame's {self._last_time_s!r} s (more than "
                                 f"{MAX_TIME_JUMP_S:g} s: milliseconds given as seconds?); "
                                 "frame rejected, the stream's clock is unchanged")
        return t, per_node, None

    def _validate_rows(self, t, detections):
        n_nodes = len(self.node_names)
        per_node: list = [None] * n_nodes
        if isinstance(detections, Mapping):
            items = []
            for name, rows in detections.items():
                if name not in self._index:
                    return t, None, f"unknown node {name!r} (the stream has {list(self.node_names)})"
                items.append((self._index[name], name, rows))
        elif isinstance(detections, Sequence) and not isinstance(detections, str):
            if len(detections) != n_nodes:
                return t, None, f"{len(detections)} detection arrays for {n_nodes} nodes"
            items = [(i, self.node_names[i], rows) for i, rows in enumerate(detections)]
        else:
            return t, None, f"detections must be a mapping or a sequence, got {type(detections).__name__}"
        for i, name, rows in items:
            z, problem = _check_rows(rows, name)
            if problem is not None:
                return t, None, problem
            per_node[i] = z
        return t, [_EMPTY_ROWS if z is None else z for z in per_node], None

    def _update(self, index, t, ok, message, fused, start, dropped=0, *, person_id=None,
                final_cost=None) -> StreamUpdate:
        track_id, track_state, track_cov = self._tracker.track_arrays()
        n_nodes = len(self.node_names)
        if fused is None:
            fused = (np.zeros((0, 4)), np.zeros((0, 4, 4)), _EMPTY_I8, np.zeros(0),
                     np.zeros((0, n_nodes), dtype=np.int64), np.zeros((0, n_nodes), dtype=bool))
        state, cov, status, degeneracy, members, rejected = fused
        return StreamUpdate(
            index=index, time_s=t, ok=ok, message=message,
            state=state, covariance=cov, status=status, members=members, degeneracy=degeneracy,
            rejected=rejected,
            track_id=track_id, track_state=track_state, track_covariance=track_cov,
            latency_s=time.perf_counter() - start, dropped_detections=dropped,
            person_id=person_id, final_cost=final_cost,
        )


_OMEGA_MAX = np.pi + 1e-9
_OK = int(Status.OK)
_EMPTY_ROWS = np.zeros((0, 3))
_INF = math.inf


def _measurements(per_node, members: NDArray) -> NDArray:
    """(G, N, 3) the measurements of the groups ``members`` (G, N); zeros where none."""
    g, n_nodes = members.shape
    z = np.zeros((g, n_nodes, 3))
    for i, row in enumerate(members.tolist()):
        for n, k in enumerate(row):
            if k >= 0:
                z[i, n] = per_node[n][k]
    return z


def _rows_of(members: NDArray, kept) -> NDArray:
    """``members`` with each node's merged rows taken back to its rows as given
    (``kept`` None: none merged)."""
    if kept is None or all(k is None for k in kept):
        return members
    out = members.copy()
    for n, k in enumerate(kept):
        if k is not None:
            has = out[:, n] >= 0
            out[has, n] = k[out[has, n]]
    return out


def _check_rows(rows, name):
    """``(z (K, 3) or None, problem message or None)`` of one node's detections."""
    try:
        z = np.asarray(rows, dtype=float)
    except (TypeError, ValueError) as exc:
        return None, f"detections of {name} are not numbers: {exc}"
    if z.size == 0:
        return _EMPTY_ROWS, None
    if z.ndim == 1 and z.shape[0] == 3:
        z = z[None]
    if z.ndim != 2 or z.shape[1] != 3:
        return None, f"detections of {name} must have shape (K, 3), got {z.shape}"
    if z.shape[0] <= 8:
        # A few rows (centroids): plain float checks (NaN fails every comparison).
        if all(0.0 <= r < _INF and abs(w) <= _OMEGA_MAX and abs(d) < _INF for r, w, d in z.tolist()):
            return z, None
    return _row_problem(z, name)


def _row_problem(z, name):
    """The checks of :func:`_check_rows` on arrays, in the order of their messages."""
    if not np.all(np.isfinite(z)):
        return None, f"detections of {name} have non-finite values"
    if np.any(z[:, 0] < 0):
        return None, f"detections of {name} have a negative range {z[:, 0].min()!r}"
    if np.any(np.abs(z[:, 1]) > _OMEGA_MAX):
        return None, f"detections of {name} have |omega| > pi ({np.abs(z[:, 1]).max()!r})"
    return z, None


def sends_empty_frame(frames_since_detection: int | None, fill_frames: int) -> bool:
    """Whether a source streams a frame in which no node has a detection,
    ``frames_since_detection`` frames after its last frame with one (None:
    no such frame yet): only the first ``fill_frames`` of a gap, the rule of
    :func:`recording_frames` (``mmsnap replay``) and of ``mmsnap live``'s
    driver, so that both push the same frames."""
    return frames_since_detection is not None and 0 < frames_since_detection <= fill_frames


def recording_frames(recording: Recording, *, source: Literal["centroids", "point_cloud"] = "centroids",
                     fill_frames: int = 5) -> Iterator[tuple[int, float, dict[str, NDArray]]]:
    """A recording's frames as a live source would send them:
    ``(frame, time_s, {node_name: (K, 3) detections})`` in frame order, with
    ``time_s = frame * frame_period_s``.

    Every frame with a detection is yielded, and after it up to
    ``fill_frames`` empty frames (no node has a detection) before the next
    one: with ``fill_frames`` at least the tracker's ``max_misses``, every
    track has ended by the last of them, so skipping the rest of a gap
    changes nothing, and a gap of any length costs at most ``fill_frames``
    steps. The last frame yielded is the recording's last frame with a
    detection. Each node's rows keep the recording's order within a frame.
    """
    if not isinstance(recording, Recording):
        raise ValidationError(f"recording must be a Recording, got {type(recording).__name__}")
    if source not in ("centroids", "point_cloud"):
        raise ValidationError(f"source must be 'centroids' or 'point_cloud', got {source!r}")
    check_count(fill_frames, "fill_frames", 0)
    names = recording.node_names
    dets = [getattr(recording.nodes[name], source) for name in names]
    sorted_rows = []
    for d in dets:
        if d is None or len(d) == 0:
            sorted_rows.append((np.zeros(0, np.int64), np.zeros((0, 3))))
            continue
        order = np.argsort(d.frame, kind="stable")
        sorted_rows.append((d.frame[order], d.measurements[order]))
    present = np.unique(np.concatenate([f for f, _ in sorted_rows]))
    period = float(recording.frame_period_s)
    empty = np.zeros((0, 3))
    for k, frame in enumerate(present):
        frame = int(frame)
        out = {}
        for name, (frames, z) in zip(names, sorted_rows):
            lo, hi = np.searchsorted(frames, [frame, frame + 1])
            out[name] = z[lo:hi]
        yield frame, frame * period, out
        stop = int(present[k + 1]) if k + 1 < present.size else frame + 1
        gap = frame + 1
        while gap < stop and sends_empty_frame(gap - frame, int(fill_frames)):
            yield gap, gap * period, {name: empty for name in names}
            gap += 1
