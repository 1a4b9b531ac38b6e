"""Live boards -> fused people, frame by frame (docs/LIVE.md, "mmsnap live").

:class:`LiveFusion` takes the boards' frames as :class:`~mmsnap_graph.io.ti.serial.reader.BoardFrame`
records arrive and groups them by their slot on the common clock (frames of
different boards within half a frame period of host time share a slot). A
slot is fused as soon as every active board has given it (or a later slot),
or when a board's frame arrived :data:`WAIT_FRAMES` frames past its start
(by the frames' own arrival times, so a backlog in the queue does not make
slots overdue), or the host clock is that far past it with no frame coming
(a board that dropped the frame or stopped; a board silent for
:data:`INACTIVE_FRAMES` frames is no longer waited for).

Each slot goes through the library's one place for each step: each board's
points projected into its plane with its mounting
(:func:`~mmsnap_graph.io.ti.point_cloud.cloud_to_detections`), clustered
into torso centroids (:func:`~mmsnap_graph.radar.cluster.torso_centroids`,
sparse clouds with ``min_samples=1`` as
:func:`~mmsnap_graph.app.pipeline.sparse_cluster_config` decides, here on the
median of the frames seen so far), then the stream's association, one-shot
fusion and central tracker (:class:`~mmsnap_graph.fusion.stream.frame_stream.FrameStream`,
the driver ``mmsnap replay`` uses). Every fused slot goes to each sink
(:class:`FusedSink`): a JSON-lines writer, a recorder, a view.

The stream is given the frames ``mmsnap replay`` gives it from the
recording ``mmsnap live --record`` writes, so that both print the same rows
(docs/LIVE.md, "Live and replay"): a slot no board gave (every board dropped
it) is an empty frame, and an empty frame (no board has a centroid) is pushed
only within ``fill_frames`` slots of the last one with a centroid
(:func:`~mmsnap_graph.fusion.stream.frame_stream.sends_empty_frame`, the
rule of :func:`~mmsnap_graph.fusion.stream.frame_stream.recording_frames`);
by then every track has ended, so the slots not pushed have no people.
"""

from __future__ import annotations

import dataclasses
import time
from collections import deque
from dataclasses import dataclass
from typing import Mapping, Protocol, Sequence

import numpy as np

from ...data.radar_config import TABLE_I
from ...data.recording import Detections
from ...fusion.stream.frame_stream import StreamUpdate, sends_empty_frame
from ...io.ti.point_cloud import Mounting, PointCloud3D, cloud_to_detections
from ...radar.chain import ChainConfig
from ...radar.cluster import torso_centroids
from ..pipeline import SPARSE_POINTS_PER_FRAME

__all__ = ["LiveFrame", "FusedSink", "LiveFusion", "WAIT_FRAMES", "INACTIVE_FRAMES",
           "replayed_frame", "live_calibration", "live_stream", "live_recording"]

#: A slot is fused at the latest this many frame periods after its start.
WAIT_FRAMES = 1.5
#: A board silent this many frames is not waited for (until it sends again).
INACTIVE_FRAMES = 10
#: Frames whose point counts decide whether the clouds are sparse.
_SPARSE_HISTORY = 200


@dataclass(frozen=True, kw_only=True, slots=True)
class LiveFrame:
    """One fused slot: ``frame`` (the slot), ``time_s`` (``frame *
    frame_period_s``), ``boards`` (the boards it holds), ``points`` (board ->
    :class:`~mmsnap_graph.data.recording.Detections` in its plane),
    ``centroids`` (board -> (K, 3) rows), ``update`` (the
    :class:`~mmsnap_graph.fusion.stream.frame_stream.StreamUpdate`),
    ``last_byte_s`` (host time of the last board frame's last byte; None
    for a slot no board gave) and ``done_s`` (host time when fused)."""

    frame: int
    time_s: float
    boards: tuple
    points: Mapping
    centroids: Mapping
    update: object
    last_byte_s: float | None
    done_s: float


def replayed_frame(frame: int, time_s: float, detections: Mapping, update) -> LiveFrame:
    """A :class:`LiveFrame` of a frame streamed from a recording (``mmsnap
    replay``): ``detections`` node -> (K, 3) rows streamed, given as both
    the points and the centroids; the host times are now."""
    now = time.monotonic()
    rows = {n: np.asarray(z, dtype=float).reshape(-1, 3) for n, z in detections.items()}
    points = {n: Detections(frame=np.full(len(z), frame, dtype=np.int64), range_m=z[:, 0],
                            omega_rad=z[:, 1], doppler_mps=z[:, 2]) for n, z in rows.items()}
    return LiveFrame(frame=int(frame), time_s=float(time_s), boards=tuple(rows), points=points,
                     centroids=rows, update=update, last_byte_s=now, done_s=now)


def live_calibration(path, names: Sequence[str]):
    """``(poses (N, 3), stored calibration)`` of ``--calibration``, read as
    ``mmsnap replay`` reads it (:func:`mmsnap_graph.app.runs.stored_calibration`:
    the poses, their covariances, the range offset; the ``/noise`` sigmas of
    a calibrated recording, the paper's for a JSON)."""
    from ...errors import CalibrationError
    from ...io import read_recording
    from ..runs import paper_noise, stored_calibration
    if str(path).lower().endswith(".json"):
        cal = stored_calibration(None, names, calibration_json=path)
        poses = dict(cal.node_poses or {})
    else:
        cal = stored_calibration(path, names)
        stored = read_recording(path, load_cubes=False).node_poses()
        poses = dict(cal.node_poses) if cal.node_poses else stored
    missing = [n for n in names if poses.get(n) is None]
    if missing:
        raise CalibrationError(f"--calibration {path} has no pose for board(s) {missing}")
    return np.array([poses[n] for n in names], dtype=float), cal.with_default_noise(*paper_noise())


def wall_executor():
    """The executor the learned walls of ``mmsnap live`` are learned in: one
    worker process at low priority (``nice`` +10), started now (its imports
    off the frames' path). The stream applies its walls at the frames
    ``mmsnap replay`` applies those it learns in line
    (:class:`~mmsnap_graph.fusion.config.LearnedWalls`); the caller shuts it
    down."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    from .refine import below_live
    pool = ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn"),
                               initializer=below_live)
    pool.submit(_ready).result()
    return pool


def _ready() -> bool:
    """The worker's first job: the walls' module imported before they are needed."""
    from ...fusion.recording import room  # noqa: F401
    return True


def live_stream(names: Sequence[str], poses, *, frame_period_s: float, config, noise,
                pose_covariances=None, range_offset_m=None, wall_executor=None):
    """The :class:`~mmsnap_graph.fusion.stream.frame_stream.FrameStream` of
    ``mmsnap live``: the tracker at the boards' frame period, as ``mmsnap
    replay`` of the recording takes it (:func:`live_recording`); the walls
    learned in ``wall_executor`` (:func:`wall_executor`; None: in line)."""
    from ...fusion.stream.frame_stream import FrameStream
    from ...tracking.central import CentralConfig
    return FrameStream(names, poses, config=config, noise=noise,
                       pose_covariances=pose_covariances, range_offset_m=range_offset_m,
                       tracker=CentralConfig(frame_period_s=float(frame_period_s)),
                       wall_executor=wall_executor)


def live_recording(collector, centroids, poses: Mapping, *, mounting: Mapping,
                   height_band_m=None, reach_m: Mapping | None = None):
    """The recording of ``mmsnap live --record``: the boards' frames
    (``collector``, a :class:`~mmsnap_graph.io.ti.serial.session.FrameCollector`)
    with each board's ``poses[name]`` and the centroids live fused
    (``centroids``, a :class:`~.sinks.CentroidLog`), which ``mmsnap replay``
    streams again; ``reach_m`` (board -> m) the coverage check's reach live
    took, declared in the metadata
    (:data:`~mmsnap_graph.fusion.recording.coverage.REACH_METADATA_KEY`)."""
    from ...fusion.recording.coverage import REACH_METADATA_KEY
    md = {REACH_METADATA_KEY.format(node=n): float(r) for n, r in (reach_m or {}).items()}
    rec = collector.recording(mounting=mounting, height_band_m=height_band_m, metadata=md)
    for name in rec.node_names:
        node = dataclasses.replace(rec.nodes[name], pose=np.asarray(poses[name], dtype=float),
                                   centroids=centroids.detections(name))
        rec = rec.with_node(node)
    return rec


class FusedSink(Protocol):
    """What a consumer of fused slots implements (JSON lines, a recorder, a view)."""

    def write(self, frame: LiveFrame) -> None: ...
    def close(self) -> None: ...


class LiveFusion:
    """Group, cluster, fuse and track the boards' frames (module docstring).

    names : the boards in the stream's node order; stream : a
    :class:`~mmsnap_graph.fusion.stream.frame_stream.FrameStream` over them;
    mounting : board -> :class:`~mmsnap_graph.io.ti.point_cloud.Mounting`;
    frame_period_s, t0_s : the common grid; sinks : the consumers;
    fill_frames : the empty frames pushed after one with a centroid (default
    the tracker's ``max_misses``, as ``mmsnap replay`` fills).
    """

    def __init__(self, names: Sequence[str], stream, *, mounting: Mapping[str, Mounting],
                 frame_period_s: float, t0_s: float, sinks: Sequence[FusedSink] = (),
                 height_band_m=None, chain: ChainConfig | None = None,
                 fill_frames: int | None = None) -> None:
        self.names = tuple(names)
        self.stream = stream
        self.mounting = dict(mounting)
        self.period = float(frame_period_s)
        self.t0_s = float(t0_s)
        self.sinks = list(sinks)
        self.height_band_m = height_band_m
        self.chain = ChainConfig() if chain is None else chain
        self._pending: dict[int, dict] = {}        # slot -> board -> BoardFrame
        self._ready: dict[int, dict] = {}          # slot -> board -> (points, centroids, rule)
        self._last_slot = {n: None for n in self.names}
        self._counts: deque = deque(maxlen=_SPARSE_HISTORY)
        self.fused = 0
        self.late = 0                   # board frames for a slot already fused
        self._next = None               # the lowest slot not yet fused
        self._first = None              # the session's first slot
        self.fill_frames = (int(stream.tracker_config.max_misses) if fill_frames is None
                            else int(fill_frames))
        self._decided: int | None = None    # the last slot fused
        self._busy: int | None = None       # the last slot with a centroid
        self.pushed = 0                     # frames given to the stream

    # ------------------------------------------------------------------
    def add(self, frame) -> list[LiveFrame]:
        """A board's frame; returns the slots this completes, fused."""
        # A late frame too says its board is active: the next slots wait for it.
        last = self._last_slot[frame.board]
        self._last_slot[frame.board] = frame.slot if last is None else max(last, frame.slot)
        if self._next is not None and frame.slot < self._next:
            self.late += 1
            return []
        self._pending.setdefault(frame.slot, {})[frame.board] = frame
        # Projected and clustered now, not when the slot is complete: the
        # slot's last frame then waits for its own clustering alone.
        self._ready.setdefault(frame.slot, {})[frame.board] = self._prepare(frame)
        if self._next is None:
            self._next = self._first = frame.slot
        # The frame's own arrival is the clock here: frames that waited in the
        # queue (a busy moment) do not make their slot overdue.
        return self.poll(frame.host_time_s)

    def poll(self, now_s: float) -> list[LiveFrame]:
        """Fuse the slots that are complete or whose wait is over."""
        out = []
        while self._pending:
            slot = min(self._pending)
            waiting = [n for n in self._active(slot) if n not in self._pending[slot]]
            overdue = now_s > self.t0_s + (slot + WAIT_FRAMES) * self.period
            if waiting and not overdue:
                break
            out.append(self._fuse(slot, self._pending.pop(slot)))
            self._next = slot + 1
        return out

    def flush(self) -> list[LiveFrame]:
        """Fuse everything still pending (the session ended)."""
        return [self._fuse(s, self._pending.pop(s)) for s in sorted(self._pending)]

    def _active(self, slot: int) -> list[str]:
        """The boards slot ``slot`` waits for: those that sent a frame in the
        last :data:`INACTIVE_FRAMES` slots (one not heard from yet counts
        from the first slot of the session: all start together)."""
        first = self._first
        return [n for n, last in self._last_slot.items()
                if (first if last is None else last) > slot - INACTIVE_FRAMES]

    # ------------------------------------------------------------------
    def _sparse(self) -> bool:
        counts = [c for c in self._counts if c > 0]
        return bool(counts) and float(np.median(counts)) < SPARSE_POINTS_PER_FRAME

    def _centroids(self, det: Detections, sparse: bool | None = None) -> np.ndarray:
        cluster = self.chain.cluster
        if (self._sparse() if sparse is None else sparse) and cluster.min_samples != 1:
            cluster = dataclasses.replace(cluster, min_samples=1)
        c = torso_centroids(det, cluster, doppler_resolution_mps=TABLE_I.doppler_resolution_mps)
        return c.measurements

    def _points(self, frame) -> Detections:
        p = frame.points
        cloud = PointCloud3D(frame=np.full(len(p["x"]), frame.slot, dtype=np.int64), x_m=p["x"],
                             y_m=p["y"], z_m=p["z"], doppler_mps=p["doppler"], snr_db=p["snr"],
                             noise_db=p["noise"])
        return cloud_to_detections(cloud, self.mounting[frame.board],
                                   height_band_m=self.height_band_m)

    def _prepare(self, frame) -> tuple:
        """A frame's points in its plane and its centroids, clustered by the
        sparse-cloud rule of the frames fused so far (``_fuse`` clusters it
        again in the rare frame where the rule it decides on differs)."""
        det = self._points(frame)
        sparse = self._sparse()
        return det, self._centroids(det, sparse), sparse

    def _fuse(self, slot: int, frames: dict) -> LiveFrame:
        if self._decided is not None:           # the slots no board gave
            for gap in range(self._decided + 1, slot):
                self._emit(gap, {}, {}, {})
        ready = self._ready.pop(slot, {})
        points, centroids = {}, {}
        for name, f in frames.items():
            det, c, sparse = ready[name] if name in ready else (self._points(f), None, None)
            self._counts.append(len(det))
            points[name] = det
            centroids[name] = c if sparse is not None and sparse == self._sparse() \
                else self._centroids(det)
        return self._emit(slot, frames, points, centroids)

    def _emit(self, slot: int, frames: dict, points: dict, centroids: dict) -> LiveFrame:
        """Push one slot (or not: module docstring) and give it to the sinks."""
        time_s = slot * self.period
        if any(len(z) for z in centroids.values()):
            self._busy = slot
        since = None if self._busy is None else slot - self._busy
        if since == 0 or sends_empty_frame(since, self.fill_frames):
            update = self.stream.push(time_s, centroids)
            self.pushed += 1
        else:
            update = self._idle(time_s)
        self._decided = slot
        self.fused += 1
        live = LiveFrame(frame=slot, time_s=time_s, boards=tuple(sorted(frames)), points=points,
                         centroids=centroids, update=update,
                         last_byte_s=max((f.host_time_s for f in frames.values()), default=None),
                         done_s=time.monotonic())
        for sink in self.sinks:
            sink.write(live)
        return live

    def _idle(self, time_s: float) -> StreamUpdate:
        """The update of a slot not pushed: no target, no track (every track
        ended within ``fill_frames`` empty frames)."""
        n = len(self.names)
        return StreamUpdate(index=-1, time_s=time_s, ok=True, message="", state=np.zeros((0, 4)),
                            covariance=np.zeros((0, 4, 4)), status=np.zeros(0, np.int8),
                            members=np.zeros((0, n), np.int64), degeneracy=np.zeros(0),
                            track_id=np.zeros(0, np.int64), track_state=np.zeros((0, 4)),
                            track_covariance=np.zeros((0, 4, 4)), latency_s=0.0,
                            rejected=np.zeros((0, n), bool))
