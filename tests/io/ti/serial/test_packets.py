"""One data-UART packet in each of TI's layouts (mmsnap_graph.io.ti.serial.packets),
encoded by tests/ti_encode.py: the out-of-box demo, the current 3D People
Tracking demo (40-byte header, TLVs 1020/1010/1011) and the legacy 3D People
Counting demo (48-byte header with its checksum, TLVs 6/7/8 whose length
counts the TLV header), told apart from the bytes."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from mmsnap_graph.io.ti.serial.packets import (BadPacket, decode_packet, header_checksum,
                                               MAGIC_WORD)
from ti_encode import encode_counting_frame, encode_oob_frame, encode_tracking_frame

RNG = np.random.default_rng(5)
R, AZ, EL, V = (RNG.uniform(1, 6, 7), RNG.uniform(-1, 1, 7), RNG.uniform(-0.4, 0.4, 7),
                RNG.uniform(-2, 2, 7))
TARGETS = np.array([[3, 0.5, 2.5, 1.1, 0.2, -0.3, 0.0], [9, -1.0, 4.0, 1.2, 0.0, 0.4, 0.0]])


def _check_spherical(p):
    xyz = np.column_stack([p.points["x"], p.points["y"], p.points["z"]])
    np.testing.assert_allclose(np.linalg.norm(xyz, axis=1), R, atol=2e-4)
    np.testing.assert_allclose(np.arctan2(xyz[:, 0], xyz[:, 1]), AZ, atol=0.0051)
    np.testing.assert_allclose(p.points["doppler"], V, atol=0.0013)
    np.testing.assert_allclose(p.points["snr"], 20.0, atol=1e-3)      # 100 (ratio) in dB


@pytest.mark.parametrize("target_bytes", [112, 124])
def test_people_tracking_packet_with_its_40_byte_header(target_bytes):
    data = encode_tracking_frame(42, R, AZ, EL, V, targets=TARGETS, target_index=[0, 3, 255],
                                 target_bytes=target_bytes)
    p = decode_packet(data)
    assert (p.layout, p.demo, p.frame_number, p.sub_frame) == ("sdk", "tracking", 42, 0)
    _check_spherical(p)
    np.testing.assert_allclose(p.targets, TARGETS, rtol=1e-6, atol=1e-7)
    assert p.target_index.tolist() == [0, 3, 255]
    assert decode_packet(data, demo="tracking").demo == "tracking"


def test_legacy_people_counting_packet_with_its_48_byte_header():
    data = encode_counting_frame(7, R, AZ, EL, V, targets=TARGETS, target_index=[1, 2],
                                 uart_sent_ms=12)
    assert header_checksum(data)
    p = decode_packet(data)
    assert (p.layout, p.demo, p.frame_number) == ("counting", "counting", 7)
    _check_spherical(p)
    np.testing.assert_allclose(p.targets, TARGETS, rtol=1e-6, atol=1e-7)
    assert p.target_index.tolist() == [1, 2] and p.transmit_time_s == pytest.approx(0.012)
    broken = bytearray(data)
    broken[24] ^= 0x01                                    # subFrameNumber, checksum now wrong
    with pytest.raises(BadPacket, match="checksum does not match"):
        decode_packet(bytes(broken), prefer="counting")


def test_an_empty_legacy_packet_is_not_read_as_a_40_byte_header():
    data = encode_counting_frame(8, [], [], [], [])
    assert decode_packet(data).layout == "counting"


def test_out_of_box_packet_and_its_uart_time():
    xyz = RNG.uniform(-2, 2, (4, 3))
    p = decode_packet(encode_oob_frame(3, xyz, [0.1, 0.2, 0.3, 0.4], [10, 11, 12, 13],
                                       [40, 41, 42, 43], transmit_us=48_500))
    assert (p.layout, p.demo, p.n_points, p.n_declared) == ("sdk", "oob", 4, 4)
    np.testing.assert_allclose(p.points["snr"], [10, 11, 12, 13])
    assert p.transmit_time_s == pytest.approx(0.0485)


def test_xwr14xx_header_without_sub_frame():
    pts = np.zeros(2, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("v", "<f4")])
    pts["y"] = [1.0, 2.0]
    body = struct.pack("<2I", 1, pts.nbytes) + pts.tobytes()
    total = 36 + len(body)
    data = MAGIC_WORD + struct.pack("<7I", 0x01000000, total, 0xA1443, 11, 0, 2, 1) + body
    p = decode_packet(data)
    assert (p.layout, p.frame_number, p.sub_frame, p.n_points) == ("sdk14", 11, 0, 2)


def test_a_packet_of_another_demo_is_refused_when_the_demo_is_named():
    with pytest.raises(BadPacket, match="a oob packet, not tracking"):
        decode_packet(encode_oob_frame(1, [[0, 1, 0]], [0.1]), demo="tracking")
    with pytest.raises(BadPacket, match="a tracking packet, not oob"):
        decode_packet(encode_tracking_frame(1, R, AZ, EL, V), demo="oob")


@pytest.mark.parametrize("cut, message", [
    (lambda d: d[:40] + struct.pack("<2I", 1010, 100) + b"\0" * 100, "not a whole number of 112"),
    (lambda d: d + b"\0" * 64, "bytes after the last of"),
])
def test_malformed_people_tracking_packets(cut, message):
    data = bytearray(cut(encode_tracking_frame(1, R, AZ, EL, V, pad=False)))
    data[12:16] = len(data).to_bytes(4, "little")
    data[32:36] = (1).to_bytes(4, "little")
    with pytest.raises(BadPacket, match=message):
        decode_packet(bytes(data))
