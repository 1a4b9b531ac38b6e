"""Test-only encoder of TI demo UART streams (the inverse of io.ti.uart).

Writes the byte layout documented in :mod:`mmsnap_graph.io.ti.uart` from
point arrays, so that reader tests start from known points.
"""

from __future__ import annotations

import struct

import numpy as np

MAGIC = struct.pack("<4H", 0x0102, 0x0304, 0x0506, 0x0708)


def _tlv(kind: int, value: bytes) -> bytes:
    return struct.pack("<2I", kind, len(value)) + value


def encode_oob_frame(frame_number: int, xyz, doppler, snr_db=None, noise_db=None, *,
                     sub_frame: int = 0, pad: bool = True) -> bytes:
    """One out-of-box demo packet: TLV 1 (points) and, with SNR, TLV 7."""
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
    tlvs.append(_tlv(6, b"\x00" * 24))          # a statistics TLV the reader skips
    body = b"".join(tlvs)
    total = 40 + len(body)
    if pad:
        total += -total % 32
    head = MAGIC + struct.pack("<8I", 0x03050004, total, 0xA1843, frame_number, 12345, n,
                               len(tlvs), sub_frame)
    return (head + body).ljust(total, b"\x0f")


def encode_tracking_frame(frame_number: int, range_m, azimuth_rad, elevation_rad, doppler_mps,
                          snr=None, *, units=(0.01, 0.01, 0.0025, 0.00025, 0.04)) -> bytes:
    """One 3D people-tracking packet with the compressed spherical TLV 1020."""
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
    body = _tlv(1020, struct.pack("<5f", *units) + rec.tobytes()) + _tlv(1010, b"")
    total = 48 + len(body)
    head = MAGIC + struct.pack("<9I2H", 0x04000000, total, 0x6843, frame_number, 0, 0, 0, 0, 0,
                               2, 0)
    return head + body
