"""UART logs (mmsnap_graph.io.ti.uart): repeated and backward frame numbers,
non-finite points (encoded by tests/ti_encode.py)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from mmsnap_graph.app.cli import main
from mmsnap_graph.errors import FileFormatError, MmsnapError, ValidationError
from mmsnap_graph.io import read_recording
from mmsnap_graph.io.ti.uart import parse_ti_uart, MAGIC_WORD, read_ti_uart
from ti_encode import encode_counting_frame, encode_oob_frame, encode_tracking_frame


def _packet(number, x=0.5, n=2):
    xyz = np.column_stack([np.full(n, x), np.linspace(2, 3, n), np.zeros(n)])
    return encode_oob_frame(number, xyz, np.full(n, 0.3), np.full(n, 20.0), np.full(n, 40.0))


def _log(numbers, x=0.5):
    return b"".join(_packet(k, x=x) for k in numbers)


def test_a_duplicated_packet_is_dropped_and_reported():
    data = _log([1, 2, 3]) + _packet(3) + _log([4, 5])
    log = parse_ti_uart(data)
    assert log.frame_numbers.tolist() == [1, 2, 3, 4, 5]
    assert len(log.points) == 10                       # frame 3 once, not twice
    (bad,) = log.bad
    assert bad.index == 3 and bad.byte_offset == len(_log([1, 2, 3]))
    assert "packet 3 (frame 3) at byte" in str(bad) and "a copy of packet 2" in str(bad)


def test_a_repeated_number_with_other_points_is_dropped_and_reported():
    data = _log([1, 2, 3]) + _packet(2, x=-1.0) + _log([4, 5])
    log = parse_ti_uart(data)
    assert log.frame_numbers.tolist() == [1, 2, 3, 4, 5]
    assert not np.any(log.points.x_m == -1.0)
    assert "frame number 2 goes back in the sequence 3, ..., 4" in str(log.bad[0])


@pytest.mark.parametrize("numbers, around", [
    ([1, 2, 3, 2 ** 31 + 4, 5, 6], "3, ..., 5"),          # one flipped bit inside
    ([2 ** 31 + 1, 2, 3, 4, 5, 6], "2, 3"),               # ... in the first header
    ([1, 2, 3, 4, 5, 2 ** 31 + 6], "5, ..., end")])       # ... in the last one
def test_one_corrupted_frame_number_is_dropped(numbers, around):
    """One flipped bit in a header used to put a frame at 2^31 (and then ask
    `process` for 16 GiB); the packet is dropped and reported."""
    log = parse_ti_uart(_log(numbers))
    assert log.frame_numbers.tolist() == [k for k in numbers if k < 2 ** 31]
    assert f"leaves the sequence {around} (a corrupted header" in str(log.bad[0])


@pytest.mark.parametrize("numbers, at", [([1, 2, 3, 4, 1, 2, 3], 4),     # radar restart
                                         ([50, 51, 52, 1, 2, 3], 3),     # joined out of order
                                         ([1, 2, 3, 3], 3)])             # last packet again
def test_frame_numbers_that_go_back_are_refused(numbers, at):
    data = b"".join(_packet(k, x=0.1 * i) for i, k in enumerate(numbers))
    offset = len(b"".join(_packet(k, x=0.1 * i) for i, k in enumerate(numbers[:at])))
    with pytest.raises(FileFormatError, match=rf"packet {at} at byte {offset} has frame "
                                              rf"{numbers[at]} .*split the log at byte {offset}"):
        parse_ti_uart(data)


def test_sub_frames_of_one_frame_are_not_repeats():
    xyz = np.array([[0.5, 2.0, 0.0]])
    data = b"".join(encode_oob_frame(f, xyz, [0.1], sub_frame=s) for f in (1, 2) for s in (0, 1))
    log = parse_ti_uart(data)
    assert log.bad == () and log.sub_frame.tolist() == [0, 1, 0, 1]


@pytest.mark.parametrize("value", [np.nan, np.inf, 3e38])
def test_a_non_finite_point_skips_only_its_frame(value):
    data = _log([1, 2]) + _packet(3, x=value) + _log([4])
    log = parse_ti_uart(data)
    assert log.frame_numbers.tolist() == [1, 2, 4]
    (bad,) = log.bad
    assert bad.frame_number == 3 and bad.byte_offset == len(_log([1, 2]))
    assert f"point 0 of 2 holds x={float(np.float32(value))!r} (not a finite number" in str(bad)


def test_cli_keeps_the_good_frames_and_names_the_bad_one(tmp_path, capsys):
    path = tmp_path / "log.bin"
    path.write_bytes(_log(range(1, 11)) + _packet(11, x=np.nan) + _log(range(12, 21)))
    assert main(["import", "ti-uart", "--node", f"S1={path}", "--frame-period", "0.05",
                 "-o", str(tmp_path / "u.h5")]) == 0
    assert "S1: skipped packet 10 (frame 11) at byte" in capsys.readouterr().err
    assert len(read_recording(tmp_path / "u.h5").nodes["S1"].point_cloud) == 38


def test_cli_refuses_a_restart_with_the_offset(tmp_path, capsys):
    path = tmp_path / "log.bin"
    path.write_bytes(_log(range(1, 6)) + _log(range(1, 4), x=2.0))
    assert main(["import", "ti-uart", "--node", f"S1={path}", "--frame-period", "0.05",
                 "-o", str(tmp_path / "u.h5")]) == 1
    err = capsys.readouterr().err
    assert f"packet 5 at byte {len(_log(range(1, 6)))} has frame 1" in err
    assert not (tmp_path / "u.h5").exists()


def test_one_log_imported_as_two_nodes_is_refused(tmp_path, capsys):
    """The same log for two nodes made calibrate and noise fail on a singular
    system; the import says what happened instead."""
    path = tmp_path / "log.bin"
    path.write_bytes(_log(range(1, 21)))
    args = ["import", "ti-uart", "--node", f"S1={path}", "--node", f"S2={path}",
            "--frame-period", "0.05", "-o", str(tmp_path / "u.h5")]
    assert main(args) == 2
    assert "nodes S1 and S2 hold the same 40 points in the same frames: one log imported " \
           "twice?" in capsys.readouterr().err
    other = tmp_path / "other.bin"
    other.write_bytes(_log(range(1, 21), x=0.7))
    args[5] = f"S2={other}"
    assert main(args) == 0


def test_seeded_sequences_never_merge_frames():
    """Seeded logs with repeats, restarts, flipped bits and non-finite points:
    the frames kept always increase (nothing merged into an earlier frame), or
    the log is refused naming a byte offset."""
    rng = np.random.default_rng(11)
    refused = kept_logs = 0
    for _ in range(150):
        numbers = list(range(1, 31))
        for _ in range(int(rng.integers(1, 4))):
            k = int(rng.integers(0, len(numbers)))
            kind = int(rng.integers(0, 4))
            if kind == 0:
                numbers.insert(k, numbers[k])                      # a repeat
            elif kind == 1:
                numbers[k:] = [n - numbers[k] + 1 for n in numbers[k:]]   # a restart
            elif kind == 2:
                numbers[k] += 2 ** int(rng.integers(10, 31))        # a flipped bit
        numbers = [n % 2 ** 32 for n in numbers]                   # uint32 on the wire
        bad_x = set(rng.choice(len(numbers), 2, replace=False).tolist())
        data = b"".join(_packet(n, x=np.nan if i in bad_x else 0.01 * i)
                        for i, n in enumerate(numbers))
        try:
            log = parse_ti_uart(data)
        except FileFormatError as exc:
            assert "split the log at byte" in str(exc) or "no readable" in str(exc)
            refused += 1
            continue
        kept_logs += 1
        assert np.all(np.diff(log.frame_numbers) > 0)
        assert np.all(np.isfinite(log.points.x_m))
    assert refused > 10 and kept_logs > 10, (refused, kept_logs)


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


@pytest.mark.parametrize("encode, demo", [(encode_tracking_frame, "tracking"),
                                          (encode_counting_frame, "counting")])
def test_people_demos_detected_from_the_bytes(encode, demo):
    """The current 3D People Tracking demo (40-byte header, TLV 1020) and the
    legacy People Counting demo (48-byte header, TLV 6): the reader expected
    a 48-byte header with TLV 1020, which no firmware sends."""
    rng = np.random.default_rng(4)
    data = b"".join(encode(k, rng.uniform(1, 6, 5), rng.uniform(-1, 1, 5), np.zeros(5),
                           np.zeros(5)) for k in range(20, 26))
    log = parse_ti_uart(data)
    assert log.demo == demo and log.bad == () and log.frame_numbers.tolist() == list(range(20, 26))
    assert len(parse_ti_uart(data, demo=demo).points) == 30


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
    with pytest.raises(FileFormatError, match="no readable frame"):
        parse_ti_uart(b"\x00" * 100)
    with pytest.raises(FileFormatError, match="no readable oob frame"):
        parse_ti_uart(MAGIC_WORD + b"\x00" * 10, demo="oob")
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


def _frames19(n_frames=10):
    """Packets of frames 1..n, 19 points each (distinct per frame)."""
    rng = np.random.default_rng(19)
    out = []
    for k in range(1, n_frames + 1):
        xyz = rng.uniform([-3, 0.5, -1], [3, 8, 1.5], size=(19, 3))
        out.append(encode_oob_frame(k, xyz, rng.uniform(-1, 1, 19), np.full(19, 20.0),
                                    np.full(19, 40.0)))
    return out


def _with_sub_frame(packet: bytes, sub_frame: int) -> bytes:
    p = bytearray(packet)
    p[36:40] = sub_frame.to_bytes(4, "little")                      # subFrameNumber
    return bytes(p)


@pytest.mark.parametrize("n_sub_frames", [None, 1])
@pytest.mark.parametrize("sub_frame", [1, 3, 7, 2 ** 31])
def test_a_corrupted_sub_frame_field_is_a_bad_packet_not_merged(n_sub_frames, sub_frame):
    """Frame 5's packet sent twice, the copy's sub-frame field corrupted: it
    was merged into frame 5 (38 points instead of 19, nothing reported)."""
    packets = _frames19()
    data = b"".join(packets[:5]) + _with_sub_frame(packets[4], sub_frame) + b"".join(packets[5:])
    log = parse_ti_uart(data, n_sub_frames=n_sub_frames)
    assert np.bincount(log.points.frame).tolist()[1:] == [19] * 10
    (bad,) = log.bad
    assert bad.index == 5 and bad.byte_offset == len(b"".join(packets[:5]))
    assert f"sub-frame {sub_frame}" in bad.reason and "corrupted header" in bad.reason


def test_cli_with_cfg_reports_a_sub_frame_the_cfg_cannot_have(tmp_path, capsys):
    packets = _frames19(20)
    path = tmp_path / "log.bin"
    path.write_bytes(b"".join(packets[:5]) + _with_sub_frame(packets[4], 1)
                     + b"".join(packets[5:]))
    from _shared import TI_DATA
    assert main(["import", "ti-uart", "--node", f"S1={path}", "--cfg",
                 str(TI_DATA / "iwr1843_oob.cfg"), "-o", str(tmp_path / "u.h5")]) == 0
    err = capsys.readouterr().err
    assert "S1: skipped packet 5 (frame 5) at byte" in err
    assert "sub-frame 1: the configuration has 1 sub-frame(s)" in err
    assert len(read_recording(tmp_path / "u.h5").nodes["S1"].point_cloud) <= 20 * 19


def test_advanced_frames_keep_their_sub_frames_and_refuse_others():
    xyz = np.array([[0.5, 2.0, 0.0]])
    data = b"".join(encode_oob_frame(f, xyz, [0.1], sub_frame=s) for f in range(1, 6)
                    for s in (0, 1))
    data += encode_oob_frame(6, xyz, [0.1], sub_frame=2)
    log = parse_ti_uart(data, n_sub_frames=2)
    assert log.sub_frame.tolist() == [0, 1] * 5
    assert "the configuration has 2 sub-frame(s), numbered 0 to 1" in log.bad[0].reason
    assert parse_ti_uart(data).bad[0].reason.startswith("sub-frame 2, which only 1 of")
