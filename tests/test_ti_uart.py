"""TI UART TLV streams (mmsnap_graph.io.ti_uart), encoded by tests/ti_encode.py."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from mmsnap_graph.errors import FileFormatError, MmsnapError, ValidationError
from mmsnap_graph.io.ti_uart import MAGIC_WORD, parse_ti_uart, read_ti_uart
from ti_encode import encode_oob_frame, encode_tracking_frame


def _frames(seed=0, n_frames=6):
    """Simulated clouds: frame number -> (xyz (n, 3), doppler, snr, noise)."""
    rng = np.random.default_rng(seed)
    out = {}
    for f in range(1, n_frames + 1):
        n = int(rng.integers(0, 5)) if f != 3 else 0          # frame 3 is empty
        xyz = rng.uniform([-3, 0.5, -1], [3, 8, 1.5], size=(n, 3))
        out[f] = (xyz, rng.uniform(-1, 1, n), np.round(rng.uniform(5, 30, n), 1),
                  np.round(rng.uniform(40, 60, n), 1))
    return out


def _stream(frames):
    return b"".join(encode_oob_frame(f, *v) for f, v in frames.items())


def test_round_trip_points_and_side_info():
    frames = _frames()
    log = parse_ti_uart(_stream(frames), frame_period_s=0.05)
    assert log.bad == ()
    assert log.frame_numbers.tolist() == list(frames)
    cloud = log.points
    for f, (xyz, dop, snr, noise) in frames.items():
        rows = cloud.frame == f
        np.testing.assert_allclose(cloud.points_xyz[rows], xyz, rtol=1e-6, atol=1e-6)
        np.testing.assert_allclose(cloud.doppler_mps[rows], dop, rtol=1e-6, atol=1e-7)
        np.testing.assert_allclose(cloud.snr_db[rows], snr, atol=1e-9)
        np.testing.assert_allclose(cloud.noise_db[rows], noise, atol=1e-9)
        np.testing.assert_allclose(cloud.time_s[rows], f * 0.05)


def test_points_without_side_info_have_nan_snr():
    xyz = np.array([[0.5, 2.0, 0.1]])
    log = parse_ti_uart(encode_oob_frame(7, xyz, [0.3]) + encode_oob_frame(8, xyz, [0.2]))
    assert np.isnan(log.points.snr_db).all() and log.frame_numbers.tolist() == [7, 8]


def test_corrupted_stream_keeps_good_frames_and_reports_bad_ones():
    frames = _frames(1, 8)
    packets = [encode_oob_frame(f, *v) for f, v in frames.items()]
    offsets = np.cumsum([0] + [len(p) for p in packets])
    packets[2] = packets[2][:30]                                    # cut inside the header
    bad_magic = bytearray(packets[4])
    bad_magic[0] = 0xFF                                             # wrong magic word
    packets[4] = bytes(bad_magic)
    broken = bytearray(packets[6])
    broken[40 + 4:40 + 8] = (10_000).to_bytes(4, "little")         # TLV length too long
    packets[6] = bytes(broken)
    data = b"garbage" + b"".join(packets) + packets[0][:50]          # truncated tail
    log = parse_ti_uart(data)
    assert log.frame_numbers.tolist() == [1, 2, 4, 6, 8]
    assert log.n_packets == 8                      # 9 magic words minus the damaged one
    reasons = [(b.index, b.reason.split(" ")[0]) for b in log.bad]
    assert reasons[0] == (-1, "7")                                  # 7 garbage bytes
    assert any("cut short" in b.reason for b in log.bad)
    assert any("without a magic word" in b.reason for b in log.bad)
    assert any("runs past the packet end" in b.reason for b in log.bad)
    assert any("truncated" in b.reason for b in log.bad)
    tlv_bad = next(b for b in log.bad if "runs past" in b.reason)
    # The byte offset of the broken packet, after the garbage and the cut one.
    expected = 7 + offsets[6] - (len(encode_oob_frame(3, *frames[3])) - 30)
    assert tlv_bad.byte_offset == expected


def test_point_count_mismatch_is_a_bad_frame():
    p = bytearray(encode_oob_frame(1, [[0, 1, 0]], [0.1]))
    p[8 + 20:8 + 24] = (5).to_bytes(4, "little")                   # numDetectedObj
    good = encode_oob_frame(2, [[0, 1, 0]], [0.1])
    log = parse_ti_uart(bytes(p) + good)
    assert log.frame_numbers.tolist() == [2]
    assert "announces 5 detected points" in log.bad[0].reason and log.bad[0].index == 0


def test_tracking_demo_spherical_points():
    rng = np.random.default_rng(3)
    r = rng.uniform(1, 6, 10)
    az = rng.uniform(-1, 1, 10)
    el = rng.uniform(-0.5, 0.5, 10)
    v = rng.uniform(-2, 2, 10)
    data = encode_tracking_frame(11, r, az, el, v) + encode_tracking_frame(12, r[:3], az[:3],
                                                                           el[:3], v[:3])
    log = parse_ti_uart(data, demo="tracking")
    assert log.frame_numbers.tolist() == [11, 12]
    rows = log.points.frame == 11
    xyz = log.points.points_xyz[rows]
    # Quantisation: 0.25 mm range, 0.01 rad angles.
    np.testing.assert_allclose(np.linalg.norm(xyz, axis=1), r, atol=2e-4)
    np.testing.assert_allclose(np.arctan2(xyz[:, 0], xyz[:, 1]), az, atol=0.0051)
    np.testing.assert_allclose(log.points.doppler_mps[rows], v, atol=0.0013)
    np.testing.assert_allclose(log.points.snr_db[rows], 20.0, atol=1e-3)


def test_errors(tmp_path):
    with pytest.raises(FileFormatError, match="no readable oob frame"):
        parse_ti_uart(b"\x00" * 100)
    with pytest.raises(FileFormatError, match="no readable oob frame"):
        parse_ti_uart(MAGIC_WORD + b"\x00" * 10)
    with pytest.raises(ValidationError, match="demo='xyz'"):
        parse_ti_uart(b"", demo="xyz")
    with pytest.raises(FileFormatError, match="does not exist"):
        read_ti_uart(tmp_path / "none.bin")
    path = tmp_path / "log.bin"
    path.write_bytes(_stream(_frames()))
    assert len(read_ti_uart(path).frame_numbers) == 6


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=400), st.integers(0, 2000), st.sampled_from(["oob", "tracking"]))
def test_reader_raises_only_project_errors(noise, cut, demo):
    data = _stream(_frames(2, 3)) + noise
    data = data[:cut] + MAGIC_WORD + noise + data[cut:]
    try:
        log = parse_ti_uart(data, demo=demo)
    except MmsnapError:
        return
    assert len(log.points) == len(log.points.frame)
