"""One TI data-UART packet (bytes) -> a :class:`UartPacket`, in every layout TI's
demos send (docs/LIVE.md, "The data port").

Every packet is little-endian and starts with the magic word ``02 01 04 03 06
05 08 07``, then a frame header, then ``numTLVs`` TLVs (``type`` uint32,
``length`` uint32, value). The header layouts (:data:`LAYOUTS`):

- ``"sdk"``, 40 bytes (mmWave SDK 3.x out-of-box demo, and the current 3D
  People Tracking demo): magic, uint32 ``version``, ``totalPacketLen`` (the
  whole packet, padded to a multiple of 32 bytes), ``platform``,
  ``frameNumber``, ``timeCpuCycles``, ``numDetectedObj``, ``numTLVs``,
  ``subFrameNumber``. A TLV's ``length`` is that of its value only.
- ``"sdk14"``, 36 bytes (xWR14xx): the same without ``subFrameNumber``.
- ``"counting"``, 48 bytes (the legacy 3D People Counting demo): magic,
  uint32 ``version``, ``totalPacketLen``, ``platform``, ``frameNumber``,
  ``subFrameNumber``, ``chirpProcessingMargin``, ``frameProcessingMargin``,
  ``trackProcessTime``, ``uartSentTime`` (ms), uint16 ``numTLVs``,
  ``checksum`` (the header's 16-bit words sum to 0xFFFF, one's complement). A
  TLV's ``length`` includes its own 8-byte header.

The TLVs read (others are skipped):

- out-of-box: 1 detected points (float32 ``x, y, z, velocity`` per point),
  7 their side info (int16 ``snr``, ``noise`` in 0.1 dB), 6 the timing
  statistics (six uint32; ``transmitOutputTime`` in microseconds: near the
  frame period the UART is saturated);
- 3D People Tracking: 1020 compressed points (five float32 units
  ``elevation, azimuth, doppler, range, snr``, then per point int8
  ``elevation``, int8 ``azimuth``, int16 ``doppler``, uint16 ``range``,
  uint16 ``snr``, each times its unit), 1010 targets (uint32 ``tid``, then
  float32 ``posX, posY, posZ, velX, velY, velZ`` and more: 112 bytes each, 124
  in some builds, sized by the TLV's length), 1011 one target index byte per
  point of the previous frame (253/254/255: weak, outside, noise), 1012
  target heights (uint32 ``tid``, float32 ``maxZ``, ``minZ``);
- legacy People Counting: 6 compressed points (the layout of 1020), 7
  targets, 8 target indices.

Spherical points become sensor-frame Cartesian with TI's convention ``x = r
cos(el) sin(az)``, ``y = r cos(el) cos(az)``, ``z = r sin(el)``.

:func:`decode_packet` tries each layout a packet could have and keeps the one
whose TLVs fill the packet exactly (up to the 32-byte padding); a packet no
layout reads is a :class:`BadPacket` with the reason.
"""

from __future__ import annotations

import hashlib
import struct
from dataclasses import dataclass, field
from typing import Iterator

import numpy as np
from numpy.typing import NDArray

from ..point_cloud import MAX_COORDINATE_M, MAX_SPEED_MPS

__all__ = ["MAGIC_WORD", "Layout", "LAYOUTS", "DEMOS", "UartPacket", "BadPacket",
           "decode_packet", "MAX_PACKET_BYTES", "MAX_SUB_FRAMES", "header_checksum",
           "TLV_DETECTED_POINTS", "TLV_STATS", "TLV_SIDE_INFO", "TLV_COMPRESSED_POINTS",
           "TLV_TARGETS", "TLV_TARGET_INDEX", "TLV_TARGET_HEIGHT"]

MAGIC_WORD = struct.pack("<4H", 0x0102, 0x0304, 0x0506, 0x0708)
TLV_DETECTED_POINTS, TLV_STATS, TLV_SIDE_INFO = 1, 6, 7
TLV_TARGETS, TLV_TARGET_INDEX, TLV_TARGET_HEIGHT, TLV_COMPRESSED_POINTS = 1010, 1011, 1012, 1020
#: Refuse packets longer than this (a corrupted length field).
MAX_PACKET_BYTES = 1 << 20
#: TI's advanced frame holds at most four sub-frames (``advFrameCfg``).
MAX_SUB_FRAMES = 4
#: The ``platform`` of an xWR14xx, whose header has no sub-frame field.
PLATFORM_XWR14 = 0xA1443
#: The padding after the last TLV: packets are padded to a multiple of 32 bytes.
_PAD = 32
#: Target records of TLV 1010 / legacy 7: 112 bytes (``I27f``), 124 in some builds.
TARGET_SIZES = (112, 124)

_TLV = struct.Struct("<2I")
_POINT = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("v", "<f4")])
_SIDE = np.dtype([("snr", "<i2"), ("noise", "<i2")])
_SPHERICAL = np.dtype([("el", "i1"), ("az", "i1"), ("v", "<i2"), ("r", "<u2"), ("snr", "<u2")])
_STATS = struct.Struct("<6I")
_HEIGHT_BYTES = 12
_CHECKSUM = "the header's checksum does not match"


@dataclass(frozen=True, slots=True)
class Layout:
    """A frame header layout: ``name``, the header ``struct``, the indices of
    its fields in the unpacked tuple (``None``: the layout has no such field)
    and whether a TLV's length counts its own 8-byte header."""

    name: str
    header: struct.Struct
    frame: int
    n_tlvs: int
    sub_frame: int | None
    n_objects: int | None
    tlv_length_includes_header: bool
    uart_sent_ms: int | None = None


LAYOUTS = {
    "sdk": Layout("sdk", struct.Struct("<8s8I"), frame=4, n_tlvs=7, sub_frame=8, n_objects=6,
                  tlv_length_includes_header=False),
    "sdk14": Layout("sdk14", struct.Struct("<8s7I"), frame=4, n_tlvs=7, sub_frame=None,
                    n_objects=6, tlv_length_includes_header=False),
    "counting": Layout("counting", struct.Struct("<8s9I2H"), frame=4, n_tlvs=10, sub_frame=5,
                       n_objects=None, tlv_length_includes_header=True, uart_sent_ms=9),
}
#: The demos a packet can come from, by the point TLV it holds: ``"oob"`` (TLV
#: 1), ``"tracking"`` (3D People Tracking, TLV 1020), ``"counting"`` (legacy
#: People Counting, 48-byte header, TLV 6).
DEMOS = ("oob", "tracking", "counting")
_LAYOUTS_OF_DEMO = {"oob": ("sdk", "sdk14"), "tracking": ("sdk",), "counting": ("counting",)}


@dataclass(frozen=True, kw_only=True, slots=True)
class UartPacket:
    """A decoded packet. ``points`` : column name -> (K,) float (``x, y, z``
    in m in the sensor frame, ``doppler`` in m/s, ``snr`` and ``noise`` in dB,
    NaN where unknown); ``targets`` : (T, 7) ``tid, x, y, z, vx, vy, vz`` of
    the board's own tracker, ``target_index`` : (K_prev,) uint8 or None;
    ``transmit_time_s`` : the UART time the board reports (TLV 6, or the
    legacy header's ``uartSentTime``), None if not sent. ``byte_offset`` and
    ``index`` place it in its stream; ``digest`` identifies its bytes."""

    frame_number: int
    sub_frame: int
    layout: str
    demo: str
    points: dict
    n_declared: int | None = None
    targets: NDArray = field(default_factory=lambda: np.zeros((0, 7)))
    target_index: NDArray | None = None
    transmit_time_s: float | None = None
    byte_offset: int = -1
    index: int = -1
    n_bytes: int = 0
    digest: bytes = b""
    host_time_s: float | None = None

    @property
    def n_points(self) -> int:
        return int(len(self.points["x"]))


class BadPacket(Exception):
    """A packet that cannot be read; the message says why."""


def header_checksum(header: bytes) -> bool:
    """Whether a legacy 48-byte header's 16-bit words sum to 0xFFFF (one's
    complement, carries folded back, as TI's visualizers check it; a plain
    16-bit wrap of the folded sum is accepted too)."""
    words = np.frombuffer(header[:48], dtype="<u2").astype(np.uint64)
    total = int(words.sum())
    folded = total
    while folded >> 16:
        folded = (folded & 0xFFFF) + (folded >> 16)
    wrapped = ((total & 0xFFFF) + (total >> 16)) & 0xFFFF
    return folded == 0xFFFF or wrapped == 0xFFFF


def _tlvs(packet: bytes, layout: Layout, n_tlvs: int) -> Iterator[tuple[int, bytes]]:
    pos, end = layout.header.size, len(packet)
    extra = 0 if layout.tlv_length_includes_header else _TLV.size
    for k in range(n_tlvs):
        if pos + _TLV.size > end:
            raise BadPacket(f"TLV {k} of {n_tlvs}: header beyond the packet end")
        kind, length = _TLV.unpack_from(packet, pos)
        if layout.tlv_length_includes_header and length < _TLV.size:
            raise BadPacket(f"TLV {k} (type {kind}) has length {length}, less than its own "
                            "8-byte header")
        stop = pos + length + extra
        if stop > end:
            raise BadPacket(f"TLV {k} (type {kind}) of {length} bytes runs past the packet end")
        yield kind, packet[pos + _TLV.size:stop]
        pos = stop
    if end - pos >= _PAD:
        raise BadPacket(f"{end - pos} bytes after the last of {n_tlvs} TLVs (more than the "
                        f"{_PAD - 1} bytes of padding)")


def _records(value: bytes, dtype: np.dtype, kind: int) -> NDArray:
    if len(value) % dtype.itemsize:
        raise BadPacket(f"TLV type {kind} holds {len(value)} bytes, not a multiple of "
                        f"{dtype.itemsize}")
    return np.frombuffer(value, dtype=dtype)


def _spherical(value: bytes, kind: int) -> dict:
    if len(value) < 20:
        raise BadPacket(f"TLV type {kind} holds {len(value)} bytes, less than its 20-byte units")
    el_u, az_u, v_u, r_u, snr_u = (np.float64(u) for u in struct.unpack_from("<5f", value))
    rec = _records(value[20:], _SPHERICAL, kind)
    el, az, r = rec["el"] * el_u, rec["az"] * az_u, rec["r"] * r_u
    snr = rec["snr"] * snr_u
    with np.errstate(all="ignore"):
        snr_db = np.where(snr > 0, 10.0 * np.log10(np.maximum(snr, 1e-300)), np.nan)
        xyz = (r * np.cos(el) * np.sin(az), r * np.cos(el) * np.cos(az), r * np.sin(el))
    return {"x": xyz[0], "y": xyz[1], "z": xyz[2], "doppler": rec["v"] * v_u, "snr": snr_db}


def _targets(value: bytes, kind: int) -> NDArray:
    sizes = [s for s in TARGET_SIZES if len(value) % s == 0]
    if not sizes:
        raise BadPacket(f"TLV type {kind} holds {len(value)} bytes, not a whole number of "
                        f"{' or '.join(map(str, TARGET_SIZES))}-byte targets")
    size = sizes[0]
    n = len(value) // size
    out = np.empty((n, 7))
    for i in range(n):
        out[i, 0] = struct.unpack_from("<I", value, i * size)[0]
        out[i, 1:] = struct.unpack_from("<6f", value, i * size + 4)
    return out


def _oob_tlv(kind: int, value: bytes, out: dict) -> None:
    if kind == TLV_DETECTED_POINTS:
        rec = _records(value, _POINT, kind)
        out["points"].update(x=rec["x"], y=rec["y"], z=rec["z"], doppler=rec["v"])
        out["demo"] = "oob"
    elif kind == TLV_SIDE_INFO:
        rec = _records(value, _SIDE, kind)
        out["side"] = {"snr": rec["snr"] * 0.1, "noise": rec["noise"] * 0.1}
    elif kind == TLV_STATS:
        if len(value) != _STATS.size:
            raise BadPacket(f"TLV type {kind} (statistics) holds {len(value)} bytes, not "
                            f"{_STATS.size}")
        out["transmit_time_s"] = _STATS.unpack(value)[1] * 1e-6
    elif kind == TLV_COMPRESSED_POINTS:
        out["points"].update(_spherical(value, kind))
        out["demo"] = "tracking"
    elif kind == TLV_TARGETS:
        out["targets"] = _targets(value, kind)
    elif kind == TLV_TARGET_INDEX:
        out["target_index"] = np.frombuffer(value, dtype=np.uint8)
    elif kind == TLV_TARGET_HEIGHT and len(value) % _HEIGHT_BYTES:
        raise BadPacket(f"TLV type {kind} holds {len(value)} bytes, not a multiple of "
                        f"{_HEIGHT_BYTES}")


def _counting_tlv(kind: int, value: bytes, out: dict) -> None:
    if kind == 6:
        out["points"].update(_spherical(value, kind))
    elif kind == 7:
        out["targets"] = _targets(value, kind)
    elif kind == 8:
        out["target_index"] = np.frombuffer(value, dtype=np.uint8)


def _check_points(points: dict, side: dict | None) -> dict:
    n = len(points.get("x", ()))
    if side is not None:
        if len(side["snr"]) != n:
            raise BadPacket(f"side info holds {len(side['snr'])} points, the point TLV {n}")
        points.update(side)
    cols = {}
    for name in ("x", "y", "z", "doppler", "snr", "noise"):
        values = np.asarray(points.get(name, np.full(n, np.nan)), dtype=float)
        if name in ("x", "y", "z", "doppler") and values.size:
            limit = MAX_SPEED_MPS if name == "doppler" else MAX_COORDINATE_M
            bad = ~(np.abs(values) <= limit)                      # NaN fails too
            if bad.any():
                k = int(np.flatnonzero(bad)[0])
                raise BadPacket(f"point {k} of {n} holds {name}={float(values[k])!r} (not a "
                                f"finite number within +-{limit:g})")
        cols[name] = values
    return cols


def _decode(packet: bytes, layout: Layout) -> UartPacket:
    head = layout.header.unpack_from(packet)
    if layout.name == "counting" and not header_checksum(packet):
        raise BadPacket(_CHECKSUM)
    out: dict = {"points": {}, "side": None, "demo": "counting" if layout.name == "counting"
                 else None, "transmit_time_s": None, "targets": None, "target_index": None}
    handle = _counting_tlv if layout.name == "counting" else _oob_tlv
    for kind, value in _tlvs(packet, layout, head[layout.n_tlvs]):
        handle(kind, value, out)
    points = _check_points(out["points"], out["side"])
    n_obj = None if layout.n_objects is None else int(head[layout.n_objects])
    demo = out["demo"] or "oob"
    if demo == "oob" and n_obj is not None and n_obj != len(points["x"]):
        raise BadPacket(f"header announces {n_obj} detected points, TLV type "
                        f"{TLV_DETECTED_POINTS} holds {len(points['x'])}")
    transmit = out["transmit_time_s"]
    if layout.uart_sent_ms is not None:
        transmit = head[layout.uart_sent_ms] * 1e-3
    targets = out["targets"] if out["targets"] is not None else np.zeros((0, 7))
    return UartPacket(frame_number=int(head[layout.frame]),
                      sub_frame=0 if layout.sub_frame is None else int(head[layout.sub_frame]),
                      layout=layout.name, demo=demo, points=points, n_declared=n_obj,
                      targets=targets, target_index=out["target_index"],
                      transmit_time_s=transmit, n_bytes=len(packet),
                      digest=hashlib.blake2b(packet, digest_size=16).digest())


def decode_packet(packet: bytes, *, demo: str = "auto", prefer: str | None = None) -> UartPacket:
    """Decode one whole packet (``totalPacketLen`` bytes from its magic word).

    demo : ``"auto"`` (any layout) or one of :data:`DEMOS` (its layouts only;
    a packet of another demo is a :class:`BadPacket`). prefer : the layout
    the stream has shown so far, tried first. Raises :class:`BadPacket`.
    """
    # The legacy layout first: its checksum makes a false match unlikely, while
    # a short legacy packet can also read as a 40-byte header without TLVs.
    names = ["counting", "sdk", "sdk14"] if demo == "auto" else list(_LAYOUTS_OF_DEMO[demo])
    if prefer in names:
        names.remove(prefer)
        names.insert(0, prefer)
    errors: dict[str, BadPacket] = {}
    for name in names:
        layout = LAYOUTS[name]
        if len(packet) < layout.header.size or (
                name == "sdk14" and demo == "auto" and prefer != name
                and struct.unpack_from("<I", packet, 16)[0] != PLATFORM_XWR14):
            continue
        try:
            decoded = _decode(packet, layout)
        except BadPacket as exc:
            errors[name] = exc
            continue
        if demo != "auto" and decoded.demo != demo:
            errors[name] = BadPacket(f"a {decoded.demo} packet, not {demo}")
            continue
        return decoded
    # The reason of the stream's own layout, else of the first layout whose
    # header fits (a failed legacy checksum only says the layout is another).
    if prefer in errors:
        raise errors[prefer]
    for name in names:
        if name in errors and not (name == "counting" and _CHECKSUM in str(errors[name])):
            raise errors[name]
    if errors:
        raise next(iter(errors.values()))
    raise BadPacket(f"{len(packet)} bytes: shorter than any frame header")
