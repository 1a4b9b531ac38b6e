"""One thread per board's data port: bytes -> packets -> frames on the common
clock (docs/LIVE.md).

:class:`BoardReader` blocks on the port's read (a timeout of
:data:`READ_TIMEOUT_S`, no busy loop), stamps each read with the host's
monotonic clock, feeds the :class:`~.stream.UartStreamParser`, keeps the
packets :class:`~.timing.FrameSequence` accepts, joins the sub-frames of a
frame, puts the frame on the common grid (:class:`~.timing.BoardClock`) and
hands each :class:`BoardFrame` to ``sink`` (e.g. a ``queue.Queue``'s
``put``). Bad packets and dropped ones are kept in ``problems`` (the last
:data:`MAX_PROBLEMS`) and counted in :meth:`BoardReader.report`.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import Callable, Protocol

import numpy as np

from ....errors import ValidationError
from .packets import UartPacket
from .stream import BadFrame, UartStreamParser
from .timing import BoardClock, FrameSequence

__all__ = ["BoardFrame", "BoardReader", "READ_TIMEOUT_S", "MAX_PROBLEMS"]

#: The data port's read timeout (s): how soon a reader sees that it must stop.
READ_TIMEOUT_S = 0.1
#: Problems (bad or dropped packets) a reader keeps for its report.
MAX_PROBLEMS = 50
_COLUMNS = ("x", "y", "z", "doppler", "snr", "noise")


class DataPort(Protocol):      # the part of pyserial's Serial used here
    @property
    def in_waiting(self) -> int: ...
    def read(self, size: int = 1) -> bytes: ...


@dataclass(frozen=True, kw_only=True, slots=True)
class BoardFrame:
    """One board's frame: ``board``, ``slot`` (its frame on the common grid),
    ``frame_number`` (the board's counter), ``host_time_s`` (when its last
    byte was read), ``start_s`` (the board clock's start of the frame, host
    time), ``points`` (column -> (K,) float, sensor frame: ``x, y, z,
    doppler, snr, noise``), ``demo``, ``n_packets`` (its sub-frames)."""

    board: str
    slot: int
    frame_number: int
    host_time_s: float
    start_s: float
    points: dict
    demo: str = "oob"
    n_packets: int = 1

    @property
    def n_points(self) -> int:
        return int(len(self.points["x"]))


class BoardReader(threading.Thread):
    """The reader thread of one board (module docstring).

    name : the board; port : its open data port; sink : called with each
    :class:`BoardFrame` (from this thread); frame_period_s, t0_s : the
    common grid; n_sub_frames : packets per frame (the ``.cfg``'s sub-frames,
    1 for a legacy frame); demo : as :class:`~.stream.UartStreamParser`.
    """

    def __init__(self, name: str, port: DataPort, sink: Callable[[BoardFrame], None], *,
                 frame_period_s: float, t0_s: float, n_sub_frames: int = 1,
                 demo: str = "auto") -> None:
        super().__init__(name=f"mmsnap-board-{name}", daemon=True)
        if not (frame_period_s > 0):
            raise ValidationError(f"frame_period_s={frame_period_s!r} must be > 0")
        self.board = name
        self.port = port
        self.sink = sink
        self.n_sub_frames = int(n_sub_frames)
        self.parser = UartStreamParser(demo=demo, n_sub_frames=self.n_sub_frames,
                                       frame_period_s=frame_period_s)
        self.sequence = FrameSequence(frame_period_s)
        self.clock = BoardClock(frame_period_s, t0_s)
        self.problems: deque = deque(maxlen=MAX_PROBLEMS)
        self.frames = 0
        self.first_host_time_s: float | None = None
        self.last_host_time_s: float | None = None
        self.error: BaseException | None = None
        self._halt = threading.Event()
        self._pending: list[UartPacket] = []

    def stop(self) -> None:
        self._halt.set()

    def run(self) -> None:
        try:
            while not self._halt.is_set():
                data = self.port.read(max(1, self.port.in_waiting))
                if data:
                    self.feed(data, time.monotonic())
            self.flush()
        except Exception as exc:                      # reported by the recorder
            self.error = exc

    # ------------------------------------------------------------------
    def feed(self, data: bytes, host_time_s: float) -> None:
        """Bytes read at ``host_time_s`` (the thread's loop; tests may call it)."""
        for item in self.parser.feed(data, host_time_s):
            if isinstance(item, BadFrame):
                self.problems.append(str(item))
                continue
            why = self.sequence.push(item.frame_number, item.sub_frame, item.digest,
                                     host_time_s)
            if why is not None:
                self.problems.append(f"packet {item.index} at byte {item.byte_offset}: {why}")
                continue
            if self.sequence.rejoined:          # a restart or a real gap: a new offset
                self.flush()
                self.clock.reset()
            self._add(item)

    def flush(self) -> None:
        """Hand on an incomplete last frame (the stream ended)."""
        if self._pending:
            self._emit()

    def _add(self, packet: UartPacket) -> None:
        if self._pending and packet.frame_number != self._pending[0].frame_number:
            self._emit()
        self._pending.append(packet)
        if packet.sub_frame >= self.n_sub_frames - 1:
            self._emit()

    def _emit(self) -> None:
        packets, self._pending = self._pending, []
        last = packets[-1]
        slot, start = self.clock.slot(last.frame_number, last.host_time_s)
        if len(packets) == 1:
            points = last.points
        else:
            points = {c: np.concatenate([p.points[c] for p in packets]) for c in _COLUMNS}
        self.frames += 1
        if self.first_host_time_s is None:
            self.first_host_time_s = last.host_time_s
        self.last_host_time_s = last.host_time_s
        self.sink(BoardFrame(board=self.board, slot=slot, frame_number=last.frame_number,
                             host_time_s=last.host_time_s, start_s=start, points=points,
                             demo=last.demo, n_packets=len(packets)))

    def report(self) -> dict:
        """The counters: frames handed on, packets good and bad, packets the
        sequence dropped, frame numbers missing, bytes skipped, saturated
        frames, restarts, clock re-anchors."""
        c = self.parser.counts
        return {"frames": self.frames, "packets": c.packets, "bad_packets": c.bad,
                "dropped_packets": self.sequence.dropped, "missing_frames": self.sequence.missing,
                "bytes": c.bytes, "bytes_skipped": c.bytes_skipped, "saturated": c.saturated,
                "rejoins": self.sequence.rejoins, "clock_reanchors": self.clock.reanchors}
