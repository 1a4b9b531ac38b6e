"""Live frames in order and on one clock (docs/LIVE.md, "One clock").

:class:`FrameSequence` is the causal twin of the file import's sequence
check (:func:`mmsnap_graph.io.ti.uart.parse_ti_uart` looks one packet
ahead; a live board cannot): a packet is accepted when its ``(frame number,
sub-frame)`` follows the last accepted one by a plausible step; a copy of a
recent packet, a step back and a jump further ahead than the host time since
the last packet allows are dropped and counted. Two dropped packets in a row
that follow each other (a board that restarted, a real gap) start the
sequence again from the second (``rejoins``). Frame numbers missing between
accepted packets are counted (``missing``).

:class:`BoardClock` puts each frame of one board on the common host clock:
the board's frame ``k`` starts at ``a + k T`` in host time, where ``a`` is the
lowest ``t_k - k T`` of the last :data:`CLOCK_WINDOW` frames (``t_k`` the
host time its last byte was read; the arrival delay, UART time and USB
latency, is only ever positive, so the minimum is the least delayed frame).
The frame's slot on the common grid ``t0 + s T`` follows the board's frame
counter (``s = s_prev + k - k_prev``) and moves to ``round((a + k T - t0) /
T)`` only when that differs from it by more than :data:`REANCHOR_FRAMES`
(a board clock drifting, a restart). Frames of several boards in one slot are
the same instant within half a frame period.
"""

from __future__ import annotations

from collections import deque

__all__ = ["FrameSequence", "BoardClock", "CLOCK_WINDOW", "REANCHOR_FRAMES",
           "MAX_FRAME_JUMP"]

#: Frames over which the clock offset is the lowest arrival (10 s at 20 fps):
#: long enough to hold a frame that arrived without delay, short enough to
#: follow a board clock's drift (50 ppm: 0.5 ms per window).
CLOCK_WINDOW = 200
#: The slot follows the frame counter until the host clock says otherwise by
#: more than this many frames.
REANCHOR_FRAMES = 0.75
#: Without a frame period, a step of more frames than this is a corrupted number.
MAX_FRAME_JUMP = 1 << 20
#: Recent packets remembered to drop copies.
_RECENT = 8


class FrameSequence:
    """Accept or drop each packet of one board, causally (module docstring).

    frame_period_s : the board's frame period (None: jumps are judged by
    :data:`MAX_FRAME_JUMP` only).
    """

    def __init__(self, frame_period_s: float | None = None) -> None:
        self.frame_period_s = frame_period_s
        self.accepted = 0
        self.dropped = 0
        self.missing = 0
        self.rejoins = 0
        self.rejoined = False          # the last accepted packet started the sequence again
        self._last: tuple[int, int] | None = None
        self._last_time: float | None = None
        self._rejected: tuple[int, int] | None = None
        self._rejected_time: float | None = None
        self._recent: deque = deque(maxlen=_RECENT)

    def _allowed(self, dt: float | None) -> float:
        if self.frame_period_s is None or dt is None:
            return MAX_FRAME_JUMP
        return 1.5 * max(dt, 0.0) / self.frame_period_s + 2

    def _follows(self, key, prev, t, t_prev) -> bool:
        if key <= prev:
            return False
        jump = key[0] - prev[0]
        dt = None if t is None or t_prev is None else t - t_prev
        return jump <= self._allowed(dt)

    def push(self, frame_number: int, sub_frame: int, digest: bytes,
             host_time_s: float | None = None) -> str | None:
        """None when the packet is accepted, else why it was dropped."""
        key = (int(frame_number), int(sub_frame))
        self.rejoined = False
        if digest in self._recent:
            self.dropped += 1
            return "a copy of a recent packet (dropped)"
        self._recent.append(digest)
        if self._last is not None and not self._follows(key, self._last, host_time_s,
                                                        self._last_time):
            rejected, self._rejected = self._rejected, key
            t_rejected, self._rejected_time = self._rejected_time, host_time_s
            if rejected is None or not self._follows(key, rejected, host_time_s, t_rejected):
                self.dropped += 1
                what = "goes back" if key <= self._last else "jumps ahead"
                return (f"frame {key[0]} (sub-frame {key[1]}) {what} after frame "
                        f"{self._last[0]} (sub-frame {self._last[1]}): dropped")
            self.rejoins += 1          # two in a row that follow each other
            self.rejoined = True
            self._last = None
        if self._last is not None:
            self.missing += max(key[0] - self._last[0] - 1, 0)
        self._last, self._last_time = key, host_time_s
        self._rejected = self._rejected_time = None
        self.accepted += 1
        return None


class BoardClock:
    """Host start time and common-grid slot of each frame of one board
    (module docstring). frame_period_s : the frame period T; t0_s : the host
    time of slot 0."""

    def __init__(self, frame_period_s: float, t0_s: float) -> None:
        self.frame_period_s = float(frame_period_s)
        self.t0_s = float(t0_s)
        self.reanchors = 0
        self._window: deque = deque()          # (k, t - k T), increasing residuals
        self._prev: tuple[int, int] | None = None   # (frame number, slot)
        self._floor = 0                             # the lowest slot still free

    def reset(self) -> None:
        """Forget the offset (the board restarted: its counter began again);
        the slots already given stay taken."""
        self._window.clear()
        if self._prev is not None:
            self._floor = self._prev[1] + 1
        self._prev = None

    def offset_s(self) -> float:
        """The current ``a`` (host time of the board's frame 0)."""
        return self._window[0][1]

    def slot(self, frame_number: int, host_time_s: float) -> tuple[int, float]:
        """``(slot, start time a + k T)`` of the board's frame ``frame_number``
        whose last byte was read at ``host_time_s``."""
        k, period = int(frame_number), self.frame_period_s
        residual = host_time_s - k * period
        while self._window and self._window[-1][1] >= residual:
            self._window.pop()
        self._window.append((k, residual))
        while self._window[0][0] <= k - CLOCK_WINDOW:
            self._window.popleft()
        start = self.offset_s() + k * period
        x = (start - self.t0_s) / period
        if self._prev is None:
            slot = round(x)
        else:
            pred = self._prev[1] + k - self._prev[0]
            slot = pred
            if abs(x - pred) > REANCHOR_FRAMES:
                slot = max(round(x), self._prev[1] + 1)
                self.reanchors += 1
        slot = max(int(slot), self._floor if self._prev is None else self._prev[1] + 1)
        self._prev = (k, slot)
        return slot, start
