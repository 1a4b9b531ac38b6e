"""The data UART as a byte stream: an incremental parser for files and ports alike.

:class:`UartStreamParser` takes the bytes as they come (a whole file at once,
or a serial port's reads of any size) and returns each packet as soon as its
last byte is in: a :class:`~.packets.UartPacket` for a good one (stamped with
the host time of the read that completed it), a :class:`BadFrame` for a bad
one. It resynchronises on the magic word, so a damaged stream keeps its good
packets, and it counts what it dropped (:class:`StreamCounts`).

A packet is bad when its header is implausible (``totalPacketLen`` beyond
:data:`~.packets.MAX_PACKET_BYTES`), when the next magic word comes before its
announced end (cut short), when no layout reads it (:func:`~.packets.decode_packet`),
or when its sub-frame number is one the configuration cannot have: at least
``n_sub_frames`` when the configuration is known, at least
:data:`~.packets.MAX_SUB_FRAMES` (TI's limit) otherwise. Bytes between
packets without a magic word are reported once per gap.

The layout of the first good packet is tried first for the next ones (a
stream keeps its demo); with ``frame_period_s`` a packet whose reported UART
time (TLV 6, or the legacy header's ``uartSentTime``) reaches
:data:`SATURATION_FRACTION` of the frame period counts as saturated.

State is bounded: the bytes of one incomplete packet (at most
:data:`~.packets.MAX_PACKET_BYTES`), the last packet's position, the counters.
"""

from __future__ import annotations

import dataclasses
import struct
from dataclasses import dataclass

from ....errors import ValidationError
from .packets import (DEMOS, LAYOUTS, MAGIC_WORD, MAX_PACKET_BYTES, MAX_SUB_FRAMES, BadPacket,
                      UartPacket, decode_packet)

__all__ = ["BadFrame", "StreamCounts", "UartStreamParser", "SATURATION_FRACTION",
           "check_sub_frame"]

#: A frame whose UART time reaches this fraction of the frame period saturates
#: the port (the next frame's output is delayed or lost).
SATURATION_FRACTION = 0.9
#: The shortest header (xWR14xx, 36 bytes); ``totalPacketLen`` below it is corrupt.
_MIN_HEADER = 36
_TOTAL = struct.Struct("<I")


@dataclass(frozen=True, slots=True)
class BadFrame:
    """A frame that could not be read: ``index`` = its position among the
    packets of the stream (0-based; -1 for bytes before any magic word),
    ``byte_offset`` = where it starts, ``reason``; ``frame_number`` = the
    frame number of its header when the header was read, ``gap`` = True for
    bytes without a magic word after packet ``index`` (not a packet)."""

    index: int
    byte_offset: int
    reason: str
    frame_number: int | None = None
    gap: bool = False

    def __str__(self) -> str:
        """What a report names: ``packet 98 (frame 100) at byte 45920:
        truncated: ...``, ``480 bytes without a magic word at byte 480, after
        packet 0 (frame 1)``, ``7 bytes before the first magic word``."""
        if self.index < 0:
            return self.reason
        frame = "" if self.frame_number is None else f" (frame {self.frame_number})"
        if self.gap:
            return f"{self.reason} at byte {self.byte_offset}, after packet {self.index}{frame}"
        return f"packet {self.index}{frame} at byte {self.byte_offset}: {self.reason}"


@dataclass(kw_only=True, slots=True)
class StreamCounts:
    """What a stream held: ``packets`` (magic words that start a packet),
    ``good``, ``bad`` (packets dropped), ``bytes_skipped`` (bytes outside any
    good or bad packet), ``saturated`` (good packets whose UART time reached
    :data:`SATURATION_FRACTION` of the frame period), ``bytes`` (all bytes fed)."""

    packets: int = 0
    good: int = 0
    bad: int = 0
    bytes_skipped: int = 0
    saturated: int = 0
    bytes: int = 0


def check_sub_frame(sub_frame: int, n_sub_frames: int | None) -> str | None:
    """Why a packet's sub-frame number is impossible, or None: ``n_sub_frames``
    is the configuration's count (None: unknown, TI's limit of
    :data:`~.packets.MAX_SUB_FRAMES` applies)."""
    limit = MAX_SUB_FRAMES if n_sub_frames is None else int(n_sub_frames)
    if 0 <= sub_frame < limit:
        return None
    if n_sub_frames is None:
        return (f"sub-frame {sub_frame}: a TI radar has at most {MAX_SUB_FRAMES} sub-frames "
                "(a corrupted header)")
    return (f"sub-frame {sub_frame}: the configuration has {limit} sub-frame(s), numbered 0 to "
            f"{limit - 1} (a corrupted header)")


class UartStreamParser:
    """Incremental reader of a TI data-UART byte stream (module docstring).

    Parameters
    ----------
    demo : ``"auto"`` (detect the layout from the bytes) or one of
        :data:`~.packets.DEMOS`.
    n_sub_frames : the configuration's sub-frames per frame (1 for a legacy
        frame), or None when unknown.
    frame_period_s : the frame period, for the saturation count (None: not counted).
    """

    def __init__(self, *, demo: str = "auto", n_sub_frames: int | None = None,
                 frame_period_s: float | None = None) -> None:
        if demo != "auto" and demo not in DEMOS:
            raise ValidationError(f"demo={demo!r} must be 'auto' or one of {list(DEMOS)}")
        if n_sub_frames is not None and not (isinstance(n_sub_frames, int)
                                             and 1 <= n_sub_frames <= MAX_SUB_FRAMES):
            raise ValidationError(f"n_sub_frames={n_sub_frames!r} must be an integer in "
                                  f"[1, {MAX_SUB_FRAMES}] or None")
        if frame_period_s is not None and not (float(frame_period_s) > 0
                                               and float(frame_period_s) < float("inf")):
            raise ValidationError(f"frame_period_s={frame_period_s!r} must be finite and > 0")
        self.demo = demo
        self.n_sub_frames = n_sub_frames
        self.frame_period_s = None if frame_period_s is None else float(frame_period_s)
        self.layout: str | None = None
        self.counts = StreamCounts()
        self._buf = bytearray()
        self._base = 0                 # stream offset of self._buf[0]
        self._gap_start: int | None = None
        self._gap_is_bad = False       # the skipped bytes belong to a bad header
        self._last: tuple[int, int | None] = (-1, None)   # last packet's index, frame

    # ------------------------------------------------------------------
    def feed(self, data: bytes, host_time_s: float | None = None) -> list:
        """The packets completed by ``data`` (good ones and :class:`BadFrame`),
        in stream order; ``host_time_s`` stamps the good ones."""
        self._buf += data
        self.counts.bytes += len(data)
        out: list = []
        while self._step(out, host_time_s):
            pass
        return out

    def finish(self) -> list:
        """The end of the stream: what is left is reported (a truncated packet, a
        last gap). The parser is then empty."""
        out: list = []
        buf = self._buf
        if buf.startswith(MAGIC_WORD):
            self._close_gap(out)
            index, offset = self.counts.packets, self._base
            self.counts.packets += 1
            self.counts.bad += 1
            hsize = LAYOUTS[self.layout].header.size if self.layout else LAYOUTS["sdk"].header.size
            if len(buf) < hsize:
                out.append(BadFrame(index, offset, f"truncated header: {len(buf)} of {hsize} "
                                                   "bytes"))
            else:
                total = _TOTAL.unpack_from(buf, 12)[0]
                frame = _TOTAL.unpack_from(buf, 20)[0]
                out.append(BadFrame(index, offset, f"truncated: {len(buf)} of {total} bytes",
                                    frame))
        else:
            self._open_gap(len(buf))
        self._drop(len(buf))
        self._close_gap(out)
        return out

    # ------------------------------------------------------------------
    def _step(self, out: list, host_time_s: float | None) -> bool:
        """Consume one packet or gap from the buffer; False when more bytes are needed."""
        buf = self._buf
        pos = buf.find(MAGIC_WORD)
        if pos < 0:
            keep = min(len(buf), len(MAGIC_WORD) - 1)       # a magic word's first bytes
            self._open_gap(len(buf) - keep)
            self._drop(len(buf) - keep)
            return False
        if pos:
            self._open_gap(pos)
            self._drop(pos)
        if len(buf) < 24:
            return False
        self._close_gap(out)
        index, offset = self.counts.packets, self._base
        total, frame = _TOTAL.unpack_from(buf, 12)[0], _TOTAL.unpack_from(buf, 20)[0]
        if not _MIN_HEADER <= total <= MAX_PACKET_BYTES:
            return self._bad(out, BadFrame(index, offset, f"implausible totalPacketLen={total}"),
                             len(MAGIC_WORD), skip_to_magic=True)
        nxt = buf.find(MAGIC_WORD, len(MAGIC_WORD), total)
        if nxt >= 0:
            return self._bad(out, BadFrame(index, offset, f"cut short: the next magic word comes "
                                           f"at byte {offset + nxt}, {nxt} bytes into a "
                                           f"{total}-byte packet", frame), nxt)
        if len(buf) < total:
            return False
        try:
            packet = decode_packet(bytes(buf[:total]), demo=self.demo, prefer=self.layout)
        except BadPacket as exc:
            return self._bad(out, BadFrame(index, offset, str(exc), frame), total)
        problem = check_sub_frame(packet.sub_frame, self.n_sub_frames)
        if problem is not None:
            return self._bad(out, BadFrame(index, offset, problem, frame), total)
        self.layout = packet.layout
        self.counts.packets += 1
        self.counts.good += 1
        period, sent = self.frame_period_s, packet.transmit_time_s
        if period is not None and sent is not None and sent >= SATURATION_FRACTION * period:
            self.counts.saturated += 1
        out.append(dataclasses.replace(packet, byte_offset=offset, index=index,
                                       host_time_s=host_time_s))
        self._last = (index, packet.frame_number)
        self._drop(total)
        return True

    def _bad(self, out: list, bad: BadFrame, n_bytes: int, skip_to_magic: bool = False) -> bool:
        self.counts.packets += 1
        self.counts.bad += 1
        out.append(bad)
        self._last = (bad.index, bad.frame_number)
        self._drop(n_bytes)
        # The bytes up to the next magic word belong to this bad packet, not a gap.
        self._gap_is_bad = skip_to_magic
        return True

    def _drop(self, n: int) -> None:
        if n:
            del self._buf[:n]
            self._base += n

    def _open_gap(self, n: int) -> None:
        if n <= 0:
            return
        self.counts.bytes_skipped += n
        if self._gap_start is None and not self._gap_is_bad:
            self._gap_start = self._base

    def _close_gap(self, out: list) -> None:
        start, self._gap_start = self._gap_start, None
        self._gap_is_bad = False
        if start is None:
            return
        n = self._base - start
        index, frame = self._last
        if index < 0:
            out.append(BadFrame(-1, start, f"{n} bytes before the first magic word"))
        else:
            out.append(BadFrame(index, start, f"{n} bytes without a magic word", frame, gap=True))
