"""The pipeline's solve and checks one frame at a time, for
:class:`~mmsnap_graph.fusion.stream.frame_stream.FrameStream`
(:mod:`mmsnap_graph.fusion.recording.pipeline`, docs/STREAMING.md "One pipeline").

:class:`StreamPipeline` solves each frame's groups once
(:func:`~mmsnap_graph.fusion.recording.pipeline.solve_groups`) and keeps the
solved rows of the last frames. A frame is decided ``delay_frames`` frames
after it arrived: :func:`~mmsnap_graph.fusion.recording.pipeline.check_rows`
runs on the rows held (the frame, the :attr:`~mmsnap_graph.fusion.config.FusionConfig.context_frames`
before it and the ``delay_frames`` after it) and the frame's rows are taken,
then :func:`~mmsnap_graph.fusion.recording.pipeline.screen_rows` with the walls
learned from the decided rows of the last
:attr:`~mmsnap_graph.fusion.config.LearnedWalls.look_back_frames` frames
(learned every :attr:`~mmsnap_graph.fusion.config.LearnedWalls.relearn_frames`
decided frames and applied
:attr:`~mmsnap_graph.fusion.config.LearnedWalls.apply_after_frames` decided
frames later: in line, or in an executor beside the stream, the same walls
at the same frames).

With ``delay_frames >= context_frames`` a frame's rows are those of the
in-memory driver (the checks see every frame they look at), except where the
walls learned so far differ from those of the whole recording. With less
delay (0: causal, every decision from past frames only) a check decides
without the frames it would look at after the row.
"""

from __future__ import annotations

import dataclasses
from collections import deque
from concurrent.futures import Executor, Future
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ...data.results import FusedSequence, Status
from ..config import (CoverageCheck, DuplicateCheck, FusionConfig, LearnedWalls, RoomCheck,
                      UnplacedCheck)
from ..recording.pipeline import (FusionNetwork, check_placement, check_rows, fused_sequence,
                                  screen_rows, solve_groups)
from ..recording.room import learn_room_walls
from ..recording.rows import FusedRows

__all__ = ["StreamPipeline", "SolvedFrame"]


@dataclass(frozen=True, kw_only=True, slots=True)
class SolvedFrame:
    """One frame's groups and their solve: ``frame`` (its number), ``members``
    (G, N) each node's row in the frame (-1: none), ``z`` (G, N, 3), ``rows``."""

    frame: int
    members: NDArray
    z: NDArray
    rows: FusedRows


def concat_rows(parts: list[FusedRows], n_nodes: int) -> FusedRows:
    out = FusedRows(sum(len(p) for p in parts), n_nodes)
    for name in FusedRows.__slots__:
        setattr(out, name, np.concatenate([getattr(p, name) for p in parts]))
    return out


#: The fields of a FusedSequence that the learned walls read
#: (:func:`~mmsnap_graph.fusion.recording.room.learn_room_walls`).
_WALL_FIELDS = ("frame", "state", "covariance", "success", "status", "observed", "rejected")


class _WallRows:
    """The decided rows of the walls' look-back as
    :func:`~mmsnap_graph.fusion.recording.room.learn_room_walls` reads them:
    the fields it reads (:data:`_WALL_FIELDS`) of the sequences ``parts``,
    concatenated (without building a FusedSequence of the other fields)."""

    def __init__(self, parts: list[FusedSequence]) -> None:
        self.node_poses = parts[0].node_poses
        for k in _WALL_FIELDS:
            setattr(self, k, np.concatenate([getattr(p, k) for p in parts]))

    def __len__(self) -> int:
        return int(self.frame.shape[0])


class _LookBack:
    """The rows of the placement check's look-back that it reads (``state``,
    ``status``, ``rejected``); a row it flags is the frame's own row ``r -
    lo`` of ``own``, flagged there (the check decides that frame alone)."""

    __slots__ = ("state", "status", "rejected", "own", "lo")

    def __init__(self, own: FusedRows, lo: int) -> None:
        self.own, self.lo = own, lo

    def flag(self, r, *args, **kwargs) -> None:
        i = int(r) - self.lo
        if 0 <= i < len(self.own):
            self.own.flag(i, *args, **kwargs)


class StreamPipeline:
    """Solve each frame when it arrives and decide it ``delay_frames`` later
    (module docstring). ``net``: the network; ``config``: the
    :class:`FusionConfig` (its ``covariance`` must be ``"laplace"``);
    ``wall_executor``: where the learned walls are learned (an executor of
    :mod:`concurrent.futures`; None: in line), when
    :attr:`~mmsnap_graph.fusion.config.LearnedWalls.apply_after_frames` is
    not 0."""

    def __init__(self, net: FusionNetwork, config: FusionConfig, delay_frames: int,
                 wall_executor: Executor | None = None) -> None:
        self.net, self.config, self.delay_frames = net, config, int(delay_frames)
        self.wall_executor = wall_executor
        self._held: deque[SolvedFrame] = deque()
        walls = config.check(LearnedWalls)
        self._walls_cfg = walls
        # No check in the reference frame: a frame's rows need no FusedSequence.
        self._screens = any(config.check(k) is not None
                            for k in (RoomCheck, LearnedWalls, DuplicateCheck))
        # The placement check looks further back than the others: it runs on
        # its look-back, they on their context (:meth:`decide`).
        self._placement = config.check(UnplacedCheck) is not None
        self._context_config = dataclasses.replace(config, checks=tuple(
            c for c in config.checks if not isinstance(c, UnplacedCheck)))
        # The coverage check's reach of each node: its farthest detection so far
        # (kept only when the check has no reach of its own for every node).
        self.reach_m = np.zeros(len(net.node_names))
        cov = config.check(CoverageCheck)
        self._needs_reach = cov is not None and not set(net.node_names) <= set(cov.reach_m or {})
        self._history: deque[FusedSequence] = deque()
        self._walls: list = []
        self._since_learned = 0
        self._decided = 0
        # Walls learned and not yet applied: (the decided frame they apply
        # from, the rows they are learned from, their walls or their future).
        self._pending: deque[tuple[int, _WallRows, list | Future]] = deque()

    def see(self, per_node) -> None:
        """A frame's detections (N arrays (K_n, 3)), for each node's reach."""
        if not self._needs_reach:
            return
        for i, d in enumerate(per_node):
            if len(d):
                far = float(np.max(d[:, 0]))
                if far > self.reach_m[i]:
                    self.reach_m[i] = far

    def solve(self, frame: int, members: NDArray, z: NDArray) -> SolvedFrame:
        """Solve one frame's groups and hold them for the checks."""
        solved = SolvedFrame(frame=int(frame), members=members, z=z,
                             rows=solve_groups(z, members >= 0, self.net, self.config))
        if members.shape[0]:
            self._held.append(solved)
        return solved

    def decide(self, frame: int) -> FusedSequence | FusedRows:
        """The rows of ``frame`` after every check, from the frames held: a
        :class:`FusedSequence`, or its :class:`FusedRows` alone when no check
        in the reference frame runs (the same state, covariance, status,
        degeneracy and rejected nodes)."""
        ctx = self.config.context_frames
        if ctx == 0 and not self._screens:
            return self._decide_alone(frame)
        back = self.config.look_back_frames
        while self._held and self._held[0].frame < frame - back:
            self._held.popleft()
        held = [h for h in self._held if h.frame <= frame + self.delay_frames]
        n_nodes = len(self.net.node_names)
        if not any(h.frame == frame for h in held):
            return self._sequence(frame, np.zeros((0, n_nodes), np.int64),
                                  FusedRows(0, n_nodes), np.zeros((0, n_nodes, 3)))
        # The checks but the placement on their context around the frame:
        # they decide its rows as on the whole look-back (context_frames).
        near = [h for h in held if h.frame >= frame - ctx]
        own, members, z = self._checked(near, frame)
        if self._placement:
            self._place(held, frame, own)
        return self._sequence(frame, members, own, z)

    def _checked(self, held: list[SolvedFrame], frame: int):
        """``(rows, members, z)`` of ``frame`` after every check but the
        placement, run on the frames ``held``."""
        n_nodes = len(self.net.node_names)
        sizes = [h.members.shape[0] for h in held]
        rows = concat_rows([h.rows for h in held], n_nodes)
        frames = np.repeat([h.frame for h in held], sizes)
        members = np.concatenate([h.members for h in held])
        z = np.concatenate([h.z for h in held])
        check_rows(rows, frames, members, z, self.net, self._context_config,
                   reach_m=self.reach_m, decide=np.array([frame]))
        mine = next(i for i, h in enumerate(held) if h.frame == frame)
        lo = int(np.sum(sizes[:mine]))
        sl = slice(lo, lo + sizes[mine])
        own = FusedRows(sizes[mine], n_nodes)
        for name in FusedRows.__slots__:
            setattr(own, name, getattr(rows, name)[sl])
        return own, members[sl], z[sl]

    def _place(self, held: list[SolvedFrame], frame: int, own: FusedRows) -> None:
        """The placement check of ``frame``'s rows ``own`` (checked), in
        place, on the look-back ``held``: its chains run over the rows as
        solved (:func:`~mmsnap_graph.fusion.recording.pipeline.check_placement`)."""
        sizes = [h.members.shape[0] for h in held]
        mine = next(i for i, h in enumerate(held) if h.frame == frame)
        lo = int(np.sum(sizes[:mine]))
        sl = slice(lo, lo + sizes[mine])
        rows = _LookBack(own, lo)
        rows.state = np.concatenate([h.rows.state for h in held])
        rows.status = np.concatenate([h.rows.status for h in held])
        rows.rejected = np.concatenate([h.rows.rejected for h in held])
        solved = rows.status == Status.OK
        rows.state[sl], rows.status[sl], rows.rejected[sl] = own.state, own.status, own.rejected
        members = np.concatenate([h.members for h in held])
        check_placement(rows, np.repeat([h.frame for h in held], sizes), members >= 0, self.net,
                        np.array([frame]), solved)

    def _decide_alone(self, frame: int) -> FusedRows:
        """The rows of ``frame`` when every check is of the frame alone."""
        while self._held and self._held[0].frame < frame:
            self._held.popleft()
        if not self._held or self._held[0].frame != frame:
            return FusedRows(0, len(self.net.node_names))
        h = self._held.popleft()
        if self.config.checks:
            check_rows(h.rows, np.full(h.members.shape[0], frame, np.int64), h.members,
                       h.z, self.net, self.config, reach_m=self.reach_m)
        return h.rows

    def _sequence(self, frame, members, rows: FusedRows, z) -> FusedSequence:
        g = members.shape[0]
        seq = fused_sequence(np.full(g, frame, np.int64), np.arange(g, dtype=np.int64),
                             np.full(g, -1, np.int64), members, rows, rows.covariance.copy(),
                             self.net, self.config)
        self._learn(seq)
        return screen_rows(seq, self.config, walls=self._walls)[0]

    def _learn(self, seq: FusedSequence) -> None:
        """Keep the decided rows of the walls' look-back; learn them again
        every ``relearn_frames`` decided frames."""
        cfg = self._walls_cfg
        if cfg is None:
            return
        if len(seq):
            self._history.append(seq)
        last = int(seq.frame[0]) if len(seq) else None
        while last is not None and self._history and \
                int(self._history[0].frame[0]) <= last - cfg.look_back_frames:
            self._history.popleft()
        self._decided += 1
        self._since_learned += 1
        if self._since_learned >= cfg.relearn_frames and self._history:
            self._since_learned = 0
            rows = _WallRows(list(self._history))
            self._pending.append((self._decided + cfg.apply_after_frames, rows,
                                  self._start_learning(rows, cfg.apply_after_frames)))
        while self._pending and self._pending[0][0] <= self._decided:
            _, rows, job = self._pending.popleft()
            self._walls = _walls_of(rows, job)

    def _start_learning(self, rows: _WallRows, apply_after: int) -> list | Future:
        """The walls of ``rows``, learned in line (no executor, or needed at
        once), or their future in the executor."""
        if self.wall_executor is None or apply_after == 0:
            return learn_room_walls(rows)
        try:
            return self.wall_executor.submit(learn_room_walls, rows)
        except RuntimeError:                # shut down, or its worker died: in line
            return learn_room_walls(rows)


def _walls_of(rows: _WallRows, job: list | Future) -> list:
    """The walls of a relearning: learned in line, or the executor's (waited
    for); learned in line from the same rows if the executor failed (a
    worker that died), so that the walls never depend on where they were
    learned."""
    if not isinstance(job, Future):
        return job
    try:
        return job.result()
    except Exception:       # noqa: BLE001 - a broken pool, a pickling failure: learn in line
        return learn_room_walls(rows)
