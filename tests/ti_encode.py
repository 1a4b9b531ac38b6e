"""Test-only encoder of TI demo UART streams (the inverse of io.ti.serial.packets).

Writes the byte layout documented in :mod:`mmsnap_graph.io.ti.serial.packets` from
point arrays, so that reader tests start from known points.
"""

from __future__ import annotations

import struct

import numpy as np

MAGIC = struct.pack("<4H", 0x0102, 0x0304, 0x0506, 0x0708)


def _tlv(kind: int, value: bytes) -> bytes:
    return struct.pack("<2I", kind, len(value)) + value


def encode_oob_frame(frame_number: int, xyz, doppler, snr_db=None, noise_db=None, *,
                     sub_frame: int = 0, pad: bool = True, transmit_us: int = 0) -> bytes:
    """One out-of-box demo packet: TLV 1 (points), with SNR TLV 7, and TLV 6
    (statistics; ``transmit_us`` its transmitOutputTime)."""
    xyz = np.asarray(xyz, dtype=float).reshape(-1, 3)
    n = xyz.shape[0]
    tlvs = []
    if n:
        pts = np.zeros(n, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("v", "<f4")])
        pts["x"], pts["y"], pts["z"] = xyz.T
        pts["v"] = doppler
        tlvs.append(_tlv(1, pts.tobytes()))
        if snr_db is not None:
            side = np.zeros(n, dtype=[("snr", "<i2"), ("noise", "<i2")])
            side["snr"] = np.round(np.asarray(snr_db) * 10)
            side["noise"] = np.round(np.asarray(noise_db if noise_db is not None
                                                else np.zeros(n)) * 10)
            tlvs.append(_tlv(7, side.tobytes()))
    tlvs.append(_tlv(6, struct.pack("<6I", 900, transmit_us, 40000, 10, 30, 20)))
    body = b"".join(tlvs)
    total = 40 + len(body)
    if pad:
        total += -total % 32
    head = MAGIC + struct.pack("<8I", 0x03050004, total, 0xA1843, frame_number, 12345, n,
                               len(tlvs), sub_frame)
    return (head + body).ljust(total, b"\x0f")


def _compressed_points(range_m, azimuth_rad, elevation_rad, doppler_mps, snr, units) -> bytes:
    """The compressed spherical points of TLV 1020 (and legacy TLV 6)."""
    r = np.asarray(range_m, dtype=float)
    n = r.shape[0]
    el_u, az_u, v_u, r_u, snr_u = units
    rec = np.zeros(n, dtype=[("el", "i1"), ("az", "i1"), ("v", "<i2"), ("r", "<u2"),
                             ("snr", "<u2")])
    rec["el"] = np.round(np.asarray(elevation_rad) / el_u)
    rec["az"] = np.round(np.asarray(azimuth_rad) / az_u)
    rec["v"] = np.round(np.asarray(doppler_mps) / v_u)
    rec["r"] = np.round(r / r_u)
    rec["snr"] = np.round((np.ones(n) * 100 if snr is None else np.asarray(snr)) / snr_u)
    return struct.pack("<5f", *units) + rec.tobytes()


def encode_targets(targets, record_bytes: int = 112) -> bytes:
    """Target records (tid, x, y, z, vx, vy, vz, then zeros) of TLV 1010 / legacy 7."""
    out = b""
    for t in np.asarray(targets, dtype=float).reshape(-1, 7):
        rec = struct.pack("<I6f", int(t[0]), *t[1:])
        out += rec.ljust(record_bytes, b"\x00")
    return out


#: The compression units of encode_tracking_frame (rad, rad, m/s, m, ratio).
UNITS = (0.01, 0.01, 0.0025, 0.00025, 0.04)


def encode_tracking_frame(frame_number: int, range_m, azimuth_rad, elevation_rad, doppler_mps,
                          snr=None, *, units=UNITS, targets=None, target_index=None,
                          target_bytes: int = 112, sub_frame: int = 0, pad: bool = True) -> bytes:
    """One packet of the current 3D People Tracking demo: the 40-byte header,
    TLV 1020 (compressed points), 1010 (targets), 1011 (indices of the
    previous frame's points); TLV lengths exclude the 8-byte TLV header."""
    points = _compressed_points(range_m, azimuth_rad, elevation_rad, doppler_mps, snr, units)
    tlvs = [_tlv(1020, points)]
    if targets is not None:
        tlvs.append(_tlv(1010, encode_targets(targets, target_bytes)))
    if target_index is not None:
        tlvs.append(_tlv(1011, np.asarray(target_index, dtype=np.uint8).tobytes()))
    body = b"".join(tlvs)
    total = 40 + len(body)
    if pad:
        total += -total % 32
    head = MAGIC + struct.pack("<8I", 0x03060000, total, 0xA6843, frame_number, 99, len(range_m),
                               len(tlvs), sub_frame)
    return (head + body).ljust(total, b"\x00")


def _checksum(header_without: bytes) -> int:
    words = np.frombuffer(header_without, dtype="<u2").astype(np.int64)
    s = int(words.sum())
    while s >> 16:
        s = (s & 0xFFFF) + (s >> 16)
    return ~s & 0xFFFF


def encode_counting_frame(frame_number: int, range_m, azimuth_rad, elevation_rad, doppler_mps,
                          snr=None, *, units=UNITS, targets=None, target_index=None,
                          uart_sent_ms: int = 5) -> bytes:
    """One packet of the legacy 3D People Counting demo: the 48-byte header
    with its checksum, TLVs 6 (points), 7 (targets), 8 (indices); TLV lengths
    include the 8-byte TLV header."""
    def tlv(kind, value):
        return struct.pack("<2I", kind, len(value) + 8) + value
    tlvs = [tlv(6, _compressed_points(range_m, azimuth_rad, elevation_rad, doppler_mps, snr,
                                      units))]
    if targets is not None:
        tlvs.append(tlv(7, encode_targets(targets)))
    if target_index is not None:
        tlvs.append(tlv(8, np.asarray(target_index, dtype=np.uint8).tobytes()))
    body = b"".join(tlvs)
    total = 48 + len(body)
    fields = (0x0A6843, total, 0xA6843, frame_number, 0, 7, 8, 2, uart_sent_ms)
    head = MAGIC + struct.pack("<9I2H", *fields, len(tlvs), 0)
    head = MAGIC + struct.pack("<9I2H", *fields, len(tlvs), _checksum(head))
    return head + body
