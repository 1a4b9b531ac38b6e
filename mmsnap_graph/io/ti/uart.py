"""TI mmWave demo UART data-port logs (TLV frames) -> 3D point clouds.

A log is the raw byte stream of a demo's data UART, as a serial port gives it
(the packet layouts, docs/LIVE.md "The data port", are read by
:mod:`.serial.packets`). The same incremental parser reads files and live
ports (:class:`~.serial.stream.UartStreamParser`): it resynchronises on the
magic word, keeps the good packets of a damaged stream, reports every bad one
with its position in the stream, byte offset and reason, and detects the demo
(out-of-box, 3D People Tracking, legacy People Counting) from the bytes.

A packet with a point that is not finite is a bad frame; so is a packet
whose sub-frame number the configuration cannot have (``n_sub_frames`` from
the ``.cfg``; without one, a sub-frame number that only a few frames of the
log hold, or beyond TI's four), a copy of an earlier packet and a packet
whose frame number leaves the sequence for one packet. Frame numbers (with
the sub-frame) only increase: one that goes back (a radar restart, logs
joined out of order) is an error naming the packet's byte offset, not merged
into the earlier frames.
"""

from __future__ import annotations

import os
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from ...errors import FileFormatError, ValidationError
from .inputs import require_file
from .point_cloud import PointCloud3D
from .serial.packets import (MAGIC_WORD, TLV_COMPRESSED_POINTS, TLV_DETECTED_POINTS,
                             TLV_SIDE_INFO, UartPacket)
from .serial.stream import BadFrame, StreamCounts, UartStreamParser

__all__ = ["MAGIC_WORD", "TLV_DETECTED_POINTS", "TLV_SIDE_INFO", "TLV_COMPRESSED_SPHERICAL",
           "BadFrame", "UartLog", "parse_ti_uart", "read_ti_uart", "missing_frames"]

TLV_COMPRESSED_SPHERICAL = TLV_COMPRESSED_POINTS
#: A last packet this many frames (about 14 hours at 20 fps) after the one
#: before it has a corrupted frame number.
MAX_FRAME_JUMP = 1 << 20
#: Without a configuration, a sub-frame number held by fewer frames than this
#: fraction of the most common one's (and by fewer than two) is corrupt.
RARE_SUB_FRAME = 0.1

Demo = Literal["auto", "oob", "tracking", "counting"]


@dataclass(frozen=True, kw_only=True, slots=True)
class UartLog:
    """The frames read from a log: ``points`` (their 3D points, frame numbers
    from the headers), ``sub_frame`` (K,) of each point, ``bad`` the frames
    that were skipped, ``n_packets`` the magic words found, ``demo`` the demo
    the packets came from, ``counts`` the stream's counters and
    ``missing_frames`` the frame numbers absent between the first and the last
    (frames the board did not send or the log lost)."""

    points: PointCloud3D
    sub_frame: NDArray
    bad: tuple = field(default=())
    n_packets: int = 0
    demo: str = "oob"
    counts: StreamCounts | None = None
    missing_frames: int = 0

    @property
    def frame_numbers(self) -> NDArray:
        """Frame numbers of the good frames (including frames with no point)."""
        return self.points.frames


def missing_frames(frame_numbers) -> int:
    """Frame numbers absent between the first and the last of increasing ones."""
    f = np.unique(np.asarray(frame_numbers, dtype=np.int64))
    return int(f[-1] - f[0] + 1 - f.size) if f.size else 0


def _rare_sub_frames(good: list[UartPacket]) -> tuple[list[UartPacket], list[BadFrame]]:
    """Without a configuration: the packets whose sub-frame number only a few
    frames hold (:data:`RARE_SUB_FRAME`) are corrupted headers."""
    frames_of = Counter()
    for sub, _ in {(p.sub_frame, p.frame_number) for p in good}:
        frames_of[sub] += 1
    top = max(frames_of.values(), default=0)
    rare = {s for s, n in frames_of.items() if n < top and n < max(2, RARE_SUB_FRAME * top)}
    if not rare:
        return good, []
    usual = sorted(s for s in frames_of if s not in rare)
    bad = [BadFrame(p.index, p.byte_offset, f"sub-frame {p.sub_frame}, which only "
                    f"{frames_of[p.sub_frame]} of the log's frames hold (the others: sub-frames "
                    f"{usual}; a corrupted header; give --cfg to name the sub-frames)",
                    p.frame_number) for p in good if p.sub_frame in rare]
    return [p for p in good if p.sub_frame not in rare], bad


def parse_ti_uart(data: bytes, *, demo: Demo = "auto", frame_period_s: float | None = None,
                  n_sub_frames: int | None = None) -> UartLog:
    """Read the frames of a UART data-port byte stream (module docstring).

    demo : ``"auto"`` (detected from the bytes), ``"oob"`` (out-of-box demo,
    TLVs 1 and 7), ``"tracking"`` (3D People Tracking, TLV 1020) or
    ``"counting"`` (legacy 3D People Counting, 48-byte header, TLV 6).
    frame_period_s : if given, each point gets the time ``frame_number *
    frame_period_s``. n_sub_frames : the configuration's sub-frames per frame
    (1 for a legacy frame; None: unknown).
    Returns the good frames' points (with the header's frame numbers) and the
    bad frames; raises :class:`FileFormatError` only when no frame is good.
    """
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise ValidationError(f"data must be bytes, got {type(data).__name__}")
    parser = UartStreamParser(demo=demo, n_sub_frames=n_sub_frames, frame_period_s=frame_period_s)
    items = parser.feed(bytes(data)) + parser.finish()
    good = [p for p in items if isinstance(p, UartPacket)]
    bad = [b for b in items if isinstance(b, BadFrame)]
    if n_sub_frames is None:
        good, rare = _rare_sub_frames(good)
        bad += rare
    if not good:
        reasons = "; ".join(str(b) for b in bad[:3])
        what = "" if demo == "auto" else f" {demo}"
        raise FileFormatError(f"no readable{what} frame in {len(data)} bytes ({reasons})")
    good, dropped = _in_sequence(good)
    bad = sorted(bad + dropped, key=lambda b: (b.byte_offset, b.gap))
    cloud, sub = _assemble(good, frame_period_s)
    return UartLog(points=cloud, sub_frame=sub, bad=tuple(bad), n_packets=parser.counts.packets,
                   demo=Counter(p.demo for p in good).most_common(1)[0][0],
                   counts=parser.counts, missing_frames=missing_frames(cloud.frames))


def _key(frame: UartPacket) -> tuple[int, int]:
    return frame.frame_number, frame.sub_frame


def _in_sequence(frames: list[UartPacket]) -> tuple[list[UartPacket], list[BadFrame]]:
    """The packets in the order of their (frame number, sub-frame), which a
    radar only ever increases. A packet equal byte for byte to an earlier one
    (sent or logged twice) and a packet whose number leaves the sequence for
    one packet (a corrupted header) are dropped and reported; any other
    repeated or backward number (a radar restart, logs joined out of order)
    is an error naming the packet and its byte offset: merging it into the
    earlier frames would mix two recordings."""
    kept: list[UartPacket] = []
    dropped: list[BadFrame] = []
    seen: dict[bytes, UartPacket] = {}
    for i, f in enumerate(frames):
        twin = seen.get(f.digest)
        if twin is not None:
            dropped.append(BadFrame(f.index, f.byte_offset, f"a copy of packet {twin.index} "
                                    "(dropped)", f.frame_number))
            continue
        after = frames[i + 1] if i + 1 < len(frames) else None
        later = frames[i + 2] if i + 2 < len(frames) else None
        first_off = (not kept and later is not None and _key(after) < _key(later)
                     and _key(f) > _key(after))
        last_off = (kept and after is None and f.frame_number - kept[-1].frame_number > MAX_FRAME_JUMP)
        if first_off or last_off or (kept and after is not None
                                     and _key(f) > _key(after) > _key(kept[-1])):
            around = (f"{after.frame_number}, {later.frame_number}" if first_off else
                      f"{kept[-1].frame_number}, ..., {'end' if after is None else after.frame_number}")
            dropped.append(BadFrame(f.index, f.byte_offset, f"frame number {f.frame_number} leaves "
                                    f"the sequence {around} (a corrupted header; dropped)",
                                    f.frame_number))
            continue
        if kept and after is not None and _key(kept[-1]) < _key(after) and _key(f) <= _key(
                kept[-1]):
            dropped.append(BadFrame(f.index, f.byte_offset, f"frame number {f.frame_number} goes back "
                                    f"in the sequence {kept[-1].frame_number}, ..., {after.frame_number} "
                                    "(a repeated or corrupted packet; dropped)", f.frame_number))
            continue
        if kept and _key(f) <= _key(kept[-1]):
            last = kept[-1]
            raise FileFormatError(
                f"packet {f.index} at byte {f.byte_offset} has frame {f.frame_number} (sub-frame "
                f"{f.sub_frame}) after frame {last.frame_number} (sub-frame {last.sub_frame}) of "
                f"packet {last.index}: frame numbers go back (the radar restarted, or logs were "
                f"joined out of order); split the log at byte {f.byte_offset} and import the "
                "parts as separate recordings")
        seen[f.digest] = f
        kept.append(f)
    return kept, dropped


def _assemble(frames: list[UartPacket], frame_period_s: float | None
              ) -> tuple[PointCloud3D, NDArray]:
    names = ("x", "y", "z", "doppler", "snr", "noise")
    cols = {k: [] for k in names}
    frame_col, sub_col = [], []
    for f in frames:
        n = len(f.points["x"])
        for k in names:
            cols[k].append(np.asarray(f.points[k], dtype=float))
        frame_col.append(np.full(n, f.frame_number, dtype=np.int64))
        sub_col.append(np.full(n, f.sub_frame, dtype=np.int64))
    cat = {k: np.concatenate(v) if v else np.zeros(0) for k, v in cols.items()}
    frame = np.concatenate(frame_col)
    time = None if frame_period_s is None else frame * float(frame_period_s)
    cloud = PointCloud3D(frame=frame, x_m=cat["x"], y_m=cat["y"], z_m=cat["z"],
                         doppler_mps=cat["doppler"], snr_db=cat["snr"], noise_db=cat["noise"],
                         time_s=time, frames=np.array([f.frame_number for f in frames], np.int64))
    return cloud, np.concatenate(sub_col)


def read_ti_uart(path: str | os.PathLike, *, demo: Demo = "auto",
                 frame_period_s: float | None = None, n_sub_frames: int | None = None) -> UartLog:
    """Read a binary log of the demo's data UART (:func:`parse_ti_uart`)."""
    p = Path(path)
    require_file(p, "UART log")
    try:
        return parse_ti_uart(p.read_bytes(), demo=demo, frame_period_s=frame_period_s,
                             n_sub_frames=n_sub_frames)
    except FileFormatError as exc:
        raise FileFormatError(f"{p}: {exc}") from None
