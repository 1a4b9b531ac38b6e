"""TI mmWave demo UART data-port logs (TLV frames) -> 3D point clouds.

A log is the raw byte stream of the demo's data UART. Every frame (packet) is
little-endian and starts with the magic word ``0x0102 0x0304 0x0506 0x0708``
(as uint16: bytes ``02 01 04 03 06 05 08 07``), then a frame header, then
``numTLVs`` TLVs (type-length-value records: ``type`` uint32, ``length``
uint32 = bytes of the value that follows).

``demo="oob"`` (the mmWave SDK 3.x out-of-box demo) -- 40-byte header: magic
(8 bytes), then uint32 ``version``, ``totalPacketLen`` (the whole packet,
header included, padded to a multiple of 32 bytes), ``platform``,
``frameNumber``, ``timeCpuCycles``, ``numDetectedObj``, ``numTLVs``,
``subFrameNumber``. TLVs read:

- type 1, detected points: per point float32 ``x, y, z`` (m) and ``velocity``
  (m/s, radial, positive = receding);
- type 7, side info of the detected points: per point int16 ``snr`` and
  ``noise`` in units of 0.1 dB.

``demo="tracking"`` (the 3D people-tracking demo) -- 48-byte header: magic,
uint32 ``version``, ``totalPacketLen``, ``platform``, ``frameNumber``,
``subFrameNumber``, ``chirpProcessingMargin``, ``frameProcessingMargin``,
``trackProcessTime``, ``uartSentTime``, uint16 ``numTLVs``, ``checksum``.
TLV read: type 1020, the compressed spherical point cloud: five float32 units
(``elevation, azimuth, doppler, range, snr``), then per point int8
``elevation``, int8 ``azimuth``, int16 ``doppler``, uint16 ``range``, uint16
``snr``, each times its unit (rad, rad, m/s, m, linear SNR). The points are
turned into Cartesian sensor coordinates with TI's convention ``x = r cos(el)
sin(az)``, ``y = r cos(el) cos(az)``, ``z = r sin(el)``.

Other TLV types (range profiles, statistics, the target list) are skipped. A
stream with bad frames keeps its good ones: every bad one is reported with
its position in the stream, byte offset and reason, and reading resumes at
the next magic word. A packet with a point that is not finite is a bad frame;
so is a copy of an earlier packet and a packet whose frame number leaves the
sequence for one packet. Frame numbers (with the sub-frame) only increase:
one that goes back (a radar restart, logs joined out of order) is an error
naming the packet's byte offset, not merged into the earlier frames.
"""

from __future__ import annotations

import hashlib
import os
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator, Literal

import numpy as np
from numpy.typing import NDArray

from ...errors import FileFormatError, ValidationError
from .inputs import require_file
from .point_cloud import MAX_COORDINATE_M, MAX_SPEED_MPS, PointCloud3D

__all__ = ["MAGIC_WORD", "TLV_DETECTED_POINTS", "TLV_SIDE_INFO", "TLV_COMPRESSED_SPHERICAL",
           "BadFrame", "UartLog", "parse_ti_uart", "read_ti_uart"]

MAGIC_WORD = struct.pack("<4H", 0x0102, 0x0304, 0x0506, 0x0708)
TLV_DETECTED_POINTS = 1
TLV_SIDE_INFO = 7
TLV_COMPRESSED_SPHERICAL = 1020
#: Refuse packets longer than this (a corrupted length field).
MAX_PACKET_BYTES = 1 << 20
#: A last packet this many frames (about 14 hours at 20 fps) after the one
#: before it has a corrupted frame number.
MAX_FRAME_JUMP = 1 << 20

_HEADER = {"oob": struct.Struct("<8s8I"), "tracking": struct.Struct("<8s9I2H")}
_TLV = struct.Struct("<2I")
_POINT = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("v", "<f4")])
_SIDE = np.dtype([("snr", "<i2"), ("noise", "<i2")])
_SPHERICAL = np.dtype([("el", "i1"), ("az", "i1"), ("v", "<i2"), ("r", "<u2"), ("snr", "<u2")])


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


@dataclass(frozen=True, kw_only=True, slots=True)
class UartLog:
    """The frames read from a log: ``points`` (their 3D points, frame numbers
    from the headers), ``sub_frame`` (K,) of each point, ``bad`` the frames
    that were skipped, ``n_packets`` the magic words found."""

    points: PointCloud3D
    sub_frame: NDArray
    bad: tuple = field(default=())
    n_packets: int = 0

    @property
    def frame_numbers(self) -> NDArray:
        """Frame numbers of the good frames (including frames with no point)."""
        return self.points.frames


@dataclass
class _Frame:
    number: int
    sub_frame: int
    n_declared: int | None
    columns: dict
    index: int = -1
    byte_offset: int = -1
    digest: bytes = b""


class _BadPacket(Exception):
    pass


def _tlvs(body: bytes, n_tlvs: int) -> Iterator[tuple[int, bytes]]:
    pos = 0
    for k in range(n_tlvs):
        if pos + _TLV.size > len(body):
            raise _BadPacket(f"TLV {k} of {n_tlvs}: header beyond the packet end")
        kind, length = _TLV.unpack_from(body, pos)
        pos += _TLV.size
        if pos + length > len(body):
            raise _BadPacket(f"TLV {k} (type {kind}) of {length} bytes runs past the packet end")
        yield kind, body[pos:pos + length]
        pos += length


def _records(value: bytes, dtype: np.dtype, kind: int) -> NDArray:
    if len(value) % dtype.itemsize:
        raise _BadPacket(f"TLV type {kind} holds {len(value)} bytes, not a multiple of "
                         f"{dtype.itemsize}")
    return np.frombuffer(value, dtype=dtype)


def _spherical(value: bytes) -> dict:
    if len(value) < 20:
        raise _BadPacket(f"TLV type {TLV_COMPRESSED_SPHERICAL} holds {len(value)} bytes, less "
                         "than its 20-byte units")
    el_u, az_u, v_u, r_u, snr_u = struct.unpack_from("<5f", value)
    rec = _records(value[20:], _SPHERICAL, TLV_COMPRESSED_SPHERICAL)
    el, az = rec["el"] * np.float64(el_u), rec["az"] * np.float64(az_u)
    r = rec["r"] * np.float64(r_u)
    snr = rec["snr"] * np.float64(snr_u)
    with np.errstate(divide="ignore"):
        snr_db = np.where(snr > 0, 10.0 * np.log10(np.maximum(snr, 1e-300)), np.nan)
    return {"x": r * np.cos(el) * np.sin(az), "y": r * np.cos(el) * np.cos(az),
            "z": r * np.sin(el), "doppler": rec["v"] * np.float64(v_u), "snr": snr_db}


def _decode_packet(packet: bytes, demo: str) -> _Frame:
    head = _HEADER[demo].unpack_from(packet)
    if demo == "oob":
        number, n_obj, n_tlvs, sub = head[4], head[6], head[7], head[8]
    else:
        number, sub, n_tlvs, n_obj = head[4], head[5], head[10], None
    cols: dict = {}
    for kind, value in _tlvs(packet[_HEADER[demo].size:], n_tlvs):
        if kind == TLV_DETECTED_POINTS and demo == "oob":
            rec = _records(value, _POINT, kind)
            cols.update(x=rec["x"], y=rec["y"], z=rec["z"], doppler=rec["v"])
        elif kind == TLV_SIDE_INFO and demo == "oob":
            rec = _records(value, _SIDE, kind)
            cols.update(snr=rec["snr"] * 0.1, noise=rec["noise"] * 0.1)
        elif kind == TLV_COMPRESSED_SPHERICAL and demo == "tracking":
            cols.update(_spherical(value))
    n = len(cols.get("x", ()))
    if n_obj is not None and n_obj != n:
        raise _BadPacket(f"header announces {n_obj} detected points, TLV type "
                         f"{TLV_DETECTED_POINTS} holds {n}")
    for name in ("snr", "noise"):
        if name in cols and len(cols[name]) != n:
            raise _BadPacket(f"side info holds {len(cols[name])} points, the point TLV {n}")
    for name in ("x", "y", "z", "doppler"):
        limit = MAX_SPEED_MPS if name == "doppler" else MAX_COORDINATE_M
        values = np.asarray(cols.get(name, ()), dtype=float)
        if values.size and not np.all(np.abs(values) <= limit):     # NaN fails too
            k = int(np.flatnonzero(~(np.abs(values) <= limit))[0])
            raise _BadPacket(f"point {k} of {n} holds {name}={float(values[k])!r} (not a "
                             f"finite number within +-{limit:g})")
    return _Frame(number=int(number), sub_frame=int(sub), n_declared=n_obj, columns=cols)


def _scan(data: bytes, demo: str) -> Iterator[_Frame | BadFrame]:
    """Walk the stream packet by packet, resynchronising on the magic word."""
    hsize = _HEADER[demo].size
    pos = data.find(MAGIC_WORD)
    if pos != 0:
        where = len(data) if pos < 0 else pos
        yield BadFrame(-1, 0, f"{where} bytes before the first magic word")
    index = 0
    while pos >= 0:
        if pos + hsize > len(data):
            yield BadFrame(index, pos, f"truncated header: {len(data) - pos} of {hsize} bytes")
            return
        header = _HEADER[demo].unpack_from(data, pos)
        total, number = header[2], int(header[4])
        nxt = data.find(MAGIC_WORD, pos + len(MAGIC_WORD))
        if not hsize <= total <= MAX_PACKET_BYTES:
            yield BadFrame(index, pos, f"implausible totalPacketLen={total}")
        elif pos + total > len(data):
            yield BadFrame(index, pos, f"truncated: {len(data) - pos} of {total} bytes", number)
        elif 0 <= nxt < pos + total:
            yield BadFrame(index, pos, f"cut short: the next magic word comes at byte {nxt}, "
                                       f"{nxt - pos} bytes into a {total}-byte packet", number)
        else:
            try:
                frame = _decode_packet(data[pos:pos + total], demo)
                frame.index, frame.byte_offset = index, pos
                frame.digest = hashlib.blake2b(data[pos:pos + total], digest_size=16).digest()
                yield frame
            except _BadPacket as exc:
                yield BadFrame(index, pos, str(exc), number)
            if pos + total < len(data) and data[pos + total:pos + total + 8] != MAGIC_WORD:
                gap = (len(data) if nxt < 0 else nxt) - pos - total
                yield BadFrame(index, pos + total, f"{gap} bytes without a magic word", number,
                               gap=True)
        index += 1
        pos = nxt


def parse_ti_uart(data: bytes, *, demo: Literal["oob", "tracking"] = "oob",
                  frame_period_s: float | None = None) -> UartLog:
    """Read the frames of a UART data-port byte stream (module docstring).

    demo : ``"oob"`` (out-of-box demo, TLVs 1 and 7) or ``"tracking"`` (3D
    people-tracking demo, TLV 1020). frame_period_s : if given, each point
    gets the time ``frame_number * frame_period_s``.
    Returns the good frames' points (with the header's frame numbers) and the
    bad frames; raises :class:`FileFormatError` only when no frame is good.
    """
    if demo not in _HEADER:
        raise ValidationError(f"demo={demo!r} must be one of {sorted(_HEADER)}")
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise ValidationError(f"data must be bytes, got {type(data).__name__}")
    data = bytes(data)
    good: list[_Frame] = []
    bad: list[BadFrame] = []
    for item in _scan(data, demo):
        (bad if isinstance(item, BadFrame) else good).append(item)
    if not good:
        reasons = "; ".join(str(b) for b in bad[:3])
        raise FileFormatError(f"no readable {demo} frame in {len(data)} bytes ({reasons})")
    good, dropped = _in_sequence(good)
    bad = sorted(bad + dropped, key=lambda b: (b.byte_offset, b.gap))
    cloud, sub = _assemble(good, frame_period_s)
    return UartLog(points=cloud, sub_frame=sub, bad=tuple(bad),
                   n_packets=data.count(MAGIC_WORD))


def _key(frame: _Frame) -> tuple[int, int]:
    return frame.number, frame.sub_frame


def _in_sequence(frames: list[_Frame]) -> tuple[list[_Frame], list[BadFrame]]:
    """The packets in the order of their (frame number, sub-frame), which a
    radar only ever increases. A packet equal byte for byte to an earlier one
    (sent or logged twice) and a packet whose number leaves the sequence for
    one packet (a corrupted header) are dropped and reported; any other
    repeated or backward number (a radar restart, logs joined out of order)
    is an error naming the packet and its byte offset: merging it into the
    earlier frames would mix two recordings."""
    kept: list[_Frame] = []
    dropped: list[BadFrame] = []
    seen: dict[bytes, _Frame] = {}
    for i, f in enumerate(frames):
        twin = seen.get(f.digest)
        if twin is not None:
            dropped.append(BadFrame(f.index, f.byte_offset, f"a copy of packet {twin.index} "
                                    "(dropped)", f.number))
            continue
        after = frames[i + 1] if i + 1 < len(frames) else None
        later = frames[i + 2] if i + 2 < len(frames) else None
        first_off = (not kept and later is not None and _key(after) < _key(later)
                     and _key(f) > _key(after))
        last_off = (kept and after is None and f.number - kept[-1].number > MAX_FRAME_JUMP)
        if first_off or last_off or (kept and after is not None
                                     and _key(f) > _key(after) > _key(kept[-1])):
            around = (f"{after.number}, {later.number}" if first_off else
                      f"{kept[-1].number}, ..., {'end' if after is None else after.number}")
            dropped.append(BadFrame(f.index, f.byte_offset, f"frame number {f.number} leaves "
                                    f"the sequence {around} (a corrupted header; dropped)",
                                    f.number))
            continue
        if kept and after is not None and _key(kept[-1]) < _key(after) and _key(f) <= _key(
                kept[-1]):
            dropped.append(BadFrame(f.index, f.byte_offset, f"frame number {f.number} goes back "
                                    f"in the sequence {kept[-1].number}, ..., {after.number} "
                                    "(a repeated or corrupted packet; dropped)", f.number))
            continue
        if kept and _key(f) <= _key(kept[-1]):
            last = kept[-1]
            raise FileFormatError(
                f"packet {f.index} at byte {f.byte_offset} has frame {f.number} (sub-frame "
                f"{f.sub_frame}) after frame {last.number} (sub-frame {last.sub_frame}) of "
                f"packet {last.index}: frame numbers go back (the radar restarted, or logs were "
                f"joined out of order); split the log at byte {f.byte_offset} and import the "
                "parts as separate recordings")
        seen[f.digest] = f
        kept.append(f)
    return kept, dropped


def _assemble(frames: list[_Frame], frame_period_s: float | None) -> tuple[PointCloud3D, NDArray]:
    names = ("x", "y", "z", "doppler", "snr", "noise")
    cols = {k: [] for k in names}
    frame_col, sub_col = [], []
    for f in frames:
        n = len(f.columns.get("x", ()))
        for k in names:
            cols[k].append(np.asarray(f.columns.get(k, np.full(n, np.nan)), dtype=float))
        frame_col.append(np.full(n, f.number, dtype=np.int64))
        sub_col.append(np.full(n, f.sub_frame, dtype=np.int64))
    cat = {k: np.concatenate(v) if v else np.zeros(0) for k, v in cols.items()}
    frame = np.concatenate(frame_col)
    time = None if frame_period_s is None else frame * float(frame_period_s)
    cloud = PointCloud3D(frame=frame, x_m=cat["x"], y_m=cat["y"], z_m=cat["z"],
                         doppler_mps=cat["doppler"], snr_db=cat["snr"], noise_db=cat["noise"],
                         time_s=time, frames=np.array([f.number for f in frames], np.int64))
    return cloud, np.concatenate(sub_col)


def read_ti_uart(path: str | os.PathLike, *, demo: Literal["oob", "tracking"] = "oob",
                 frame_period_s: float | None = None) -> UartLog:
    """Read a binary log of the demo's data UART (:func:`parse_ti_uart`)."""
    p = Path(path)
    require_file(p, "UART log")
    try:
        return parse_ti_uart(p.read_bytes(), demo=demo, frame_period_s=frame_period_s)
    except FileFormatError as exc:
        raise FileFormatError(f"{p}: {exc}") from None
