"""Import of DCA1000 / mmWave Studio raw captures (layout: mmsnap_graph.io.ti.dca1000)."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from numpy.testing import assert_array_equal

from mmsnap_graph import ConfigurationError, FileFormatError, RadarConfig, ValidationError
from mmsnap_graph.io import (
    frame_bytes,
    iter_dca1000_frames,
    read_dca1000_bin,
    read_recording,
    recording_from_dca1000,
    write_dca1000_bin,
    write_recording,
)

CFG = RadarConfig(n_samples=6, n_loops=3, chirp_period_s=20e-6)  # 3 Tx x 4 Rx


def _value(f, loop, tx, rx, n):
    """A distinct int16 I and Q for every sample, to catch any misplacement."""
    i = 1000 * f + 100 * loop + 10 * (tx * 4 + rx) + n
    return i, -i - 7


def _capture_bytes(cfg, n_frames, *, iq_swap=False):
    """The capture tool's byte order, written out element by element (SWRA581):
    frames, chirps (loop-major, Tx in firing order), receivers, samples, then
    pairs of complex samples packed as I[k] I[k+1] Q[k] Q[k+1], int16 LE."""
    stream = []
    for f in range(n_frames):
        for loop in range(cfg.n_loops):
            for tx in range(cfg.n_tx):
                for rx in range(cfg.n_rx):
                    for n in range(cfg.n_samples):
                        stream.append(_value(f, loop, tx, rx, n))
    out = bytearray()
    for k in range(0, len(stream), 2):
        (i0, q0), (i1, q1) = stream[k], stream[k + 1]
        if iq_swap:
            i0, q0, i1, q1 = q0, i0, q1, i1
        out += struct.pack("<hhhh", i0, i1, q0, q1)
    return bytes(out)


def _expected(cfg, n_frames):
    cube = np.zeros((n_frames, *cfg.cube_shape), dtype=np.complex64)
    for f in range(n_frames):
        for loop in range(cfg.n_loops):
            for tx in range(cfg.n_tx):
                for rx in range(cfg.n_rx):
                    for n in range(cfg.n_samples):
                        i, q = _value(f, loop, tx, rx, n)
                        cube[f, n, loop, tx * cfg.n_rx + rx] = complex(i, q)
    return cube


def test_import_synthetic_capture_in_tool_byte_order(tmp_path):
    path = tmp_path / "adc_data.bin"
    path.write_bytes(_capture_bytes(CFG, 3))
    assert path.stat().st_size == 3 * frame_bytes(CFG)
    cube = read_dca1000_bin(path, CFG)
    assert cube.shape == (3, 6, 3, 12) and cube.dtype == np.complex64
    assert_array_equal(cube, _expected(CFG, 3))
    # Spot checks of the layout: frame 2, loop 1, Tx 2, Rx 3, sample 5.
    assert cube[2, 5, 1, 2 * 4 + 3] == complex(2000 + 100 + 110 + 5, -(2000 + 100 + 110 + 5) - 7)
    # Chunked iteration gives the same data.
    chunks = list(iter_dca1000_frames(path, CFG, chunk_frames=2))
    assert [fr.tolist() for fr, _ in chunks] == [[0, 1], [2]]
    assert_array_equal(np.concatenate([c for _, c in chunks]), cube)


def test_iq_swap_and_split_files(tmp_path):
    data = _capture_bytes(CFG, 2, iq_swap=True)
    cut = 1234  # mmWave Studio splits anywhere, even inside a frame
    (tmp_path / "adc_data_0.bin").write_bytes(data[:cut])
    (tmp_path / "adc_data_1.bin").write_bytes(data[cut:])
    parts = [tmp_path / "adc_data_0.bin", tmp_path / "adc_data_1.bin"]
    assert_array_equal(read_dca1000_bin(parts, CFG, iq_swap=True), _expected(CFG, 2))
    assert not np.array_equal(read_dca1000_bin(parts, CFG), _expected(CFG, 2))


def test_writer_is_the_inverse_and_matches_tool_bytes(tmp_path):
    path = write_dca1000_bin(tmp_path / "w.bin", _expected(CFG, 2), CFG)
    assert path.read_bytes() == _capture_bytes(CFG, 2)
    write_dca1000_bin(tmp_path / "s.bin", _expected(CFG, 2), CFG, iq_swap=True)
    assert (tmp_path / "s.bin").read_bytes() == _capture_bytes(CFG, 2, iq_swap=True)
    with pytest.raises(ValidationError, match="int16 range"):
        write_dca1000_bin(tmp_path / "x.bin", np.full((1, *CFG.cube_shape), 4e4), CFG)


def test_truncated_and_mismatched_captures(tmp_path):
    data = _capture_bytes(CFG, 3)
    trunc = tmp_path / "t.bin"
    trunc.write_bytes(data[:-8])
    with pytest.raises(FileFormatError, match=r"2 whole frames of 864 bytes \+ 856 bytes: truncated"):
        read_dca1000_bin(trunc, CFG)
    with pytest.warns(UserWarning, match=r"dropped the incomplete last frame \(856 of 864"):
        cube = read_dca1000_bin(trunc, CFG, allow_partial_frame=True)
    assert_array_equal(cube, _expected(CFG, 2))
    odd = tmp_path / "o.bin"
    odd.write_bytes(data[:-1])
    with pytest.raises(FileFormatError, match="not a whole number of int16"):
        read_dca1000_bin(odd, CFG)
    good = tmp_path / "g.bin"
    good.write_bytes(data)
    with pytest.raises(FileFormatError, match="expected n_frames=4"):
        read_dca1000_bin(good, CFG, n_frames=4)
    # A capture made with 4 loops read with 3: the size does not fit.
    other = RadarConfig(n_samples=6, n_loops=4, chirp_period_s=20e-6)
    with pytest.raises(FileFormatError, match="differs from the capture's"):
        read_dca1000_bin(good, other)
    small = tmp_path / "s.bin"
    small.write_bytes(data[:100])
    with pytest.raises(FileFormatError, match="less than one frame"), pytest.warns(UserWarning):
        read_dca1000_bin(small, CFG, allow_partial_frame=True)
    (tmp_path / "e.bin").write_bytes(b"")
    with pytest.raises(FileFormatError, match="is empty"):
        read_dca1000_bin(tmp_path / "e.bin", CFG)
    with pytest.raises(FileFormatError, match="does not exist"):
        read_dca1000_bin(tmp_path / "none.bin", CFG)


def test_inconsistent_configurations():
    five_rx = RadarConfig(n_samples=6, n_loops=3, chirp_period_s=20e-6,
                          rx_azimuth_half_wl=(0, 1, 2, 3, 4))
    with pytest.raises(ConfigurationError, match="n_rx=5 receivers"):
        frame_bytes(five_rx)
    odd = RadarConfig(n_samples=5, n_loops=3, chirp_period_s=20e-6,
                      tx_azimuth_half_wl=(0.0,), tx_elevation_half_wl=(0.0,),
                      rx_azimuth_half_wl=(0, 1, 2))
    with pytest.raises(ConfigurationError, match="is odd"):
        frame_bytes(odd)
    with pytest.raises(ConfigurationError, match="must be a RadarConfig"):
        frame_bytes({"n_samples": 6})


def test_recording_from_captures_round_trips(tmp_path):
    for name, n in (("S1", 2), ("S2", 2)):
        (tmp_path / f"{name}.bin").write_bytes(_capture_bytes(CFG, n))
    rec = recording_from_dca1000({"S1": tmp_path / "S1.bin", "S2": tmp_path / "S2.bin"}, CFG,
                                 poses={"S1": [0, 0, 0]})
    assert rec.node_names == ["S1", "S2"] and rec.nodes["S2"].pose is None
    back = read_recording(write_recording(tmp_path / "r.h5", rec))
    assert_array_equal(back.nodes["S2"].cube, _expected(CFG, 2))
    assert back.nodes["S1"].radar == CFG


# ---- advanced frames: sub-frame selection (issue 14) ---------------------------------
SUB_A = RadarConfig(n_samples=4, n_loops=2, chirp_period_s=20e-6, tx_azimuth_half_wl=(0, 4),
                    tx_elevation_half_wl=(0, 0))                       # 2 Tx
SUB_B = CFG                                                            # 3 Tx x 3 loops x 6


def _advanced_capture(n_frames):
    """Frames of [SUB_A, SUB_A, SUB_B] with distinct values per frame and sub-frame."""
    parts = []
    for f in range(n_frames):
        for k, cfg in enumerate((SUB_A, SUB_A, SUB_B)):
            parts.append(_capture_bytes(cfg, 1) if k == 2 else
                         np.full(frame_bytes(cfg) // 2, 100 * f + k, "<i2").tobytes())
    return parts


def test_sub_frame_selection_by_offset_and_stride(tmp_path):
    from mmsnap_graph.io.ti.dca1000 import read_dca1000_sub_frame, sub_frame_layout
    configs = [SUB_A, SUB_A, SUB_B]
    offset, stride = sub_frame_layout(configs, 2)
    assert (offset, stride) == (2 * frame_bytes(SUB_A), 2 * frame_bytes(SUB_A) + frame_bytes(CFG))
    path = tmp_path / "adv.bin"
    path.write_bytes(b"".join(_advanced_capture(3)))
    cube = read_dca1000_sub_frame(path, configs, 2)
    expected = _expected(CFG, 1)
    assert cube.shape == (3, *CFG.cube_shape)
    for f in range(3):
        assert_array_equal(cube[f], expected[0])
    second = read_dca1000_sub_frame(path, configs, 1)
    assert_array_equal(second.real[:, 0, 0, 0], [1, 101, 201])
    same = read_dca1000_bin(path, CFG, offset_bytes=offset, stride_bytes=stride)
    assert_array_equal(same, cube)
    chunks = list(iter_dca1000_frames(path, CFG, chunk_frames=2, offset_bytes=offset,
                                      stride_bytes=stride))
    assert [c[0].tolist() for c in chunks] == [[0, 1], [2]]
    assert_array_equal(np.concatenate([c[1] for c in chunks]), cube)


def test_sub_frame_errors_are_never_silent(tmp_path):
    from mmsnap_graph.io.ti.dca1000 import read_dca1000_sub_frame
    configs = [SUB_A, SUB_A, SUB_B]
    parts = _advanced_capture(3)
    path = tmp_path / "adv.bin"
    path.write_bytes(b"".join(parts)[:-16])
    stride = 2 * frame_bytes(SUB_A) + frame_bytes(CFG)
    with pytest.raises(FileFormatError, match=rf"2 whole frames of {stride} bytes \(stride; "
                                              rf"the selected sub-frame is {frame_bytes(CFG)} "
                                              rf"bytes at offset {2 * frame_bytes(SUB_A)}\)"):
        read_dca1000_sub_frame(path, configs, 2)
    with pytest.raises(ValidationError, match=r"sub_frame=3 .*must be in 0..2"):
        read_dca1000_sub_frame(path, configs, 3)
    with pytest.raises(ConfigurationError, match="does not fit in stride_bytes"):
        read_dca1000_bin(path, CFG, offset_bytes=8, stride_bytes=frame_bytes(CFG))
    with pytest.raises(ValidationError, match="multiples of 4"):
        read_dca1000_bin(path, CFG, offset_bytes=2, stride_bytes=2 * frame_bytes(CFG))


def test_long_file_lists_are_shortened(tmp_path):
    data = _capture_bytes(CFG, 3)[:-8]
    paths = []
    for k in range(101):
        p = tmp_path / f"adc_data_{k}.bin"
        p.write_bytes(data if k == 0 else b"")
        paths.append(p)
    with pytest.raises(FileFormatError) as info:
        read_dca1000_bin(paths, CFG)
    message = str(info.value)
    assert "101 files" in message and "adc_data_100.bin" in message
    assert "adc_data_50.bin" not in message


def test_real_adc_is_refused():
    real = RadarConfig(n_samples=6, n_loops=3, chirp_period_s=20e-6, complex_adc=False)
    with pytest.raises(ConfigurationError, match="real-ADC"):
        frame_bytes(real)


def test_recording_from_an_advanced_capture(tmp_path):
    path = tmp_path / "adv.bin"
    path.write_bytes(b"".join(_advanced_capture(2)))
    rec = recording_from_dca1000({"S1": path}, [SUB_A, SUB_A, SUB_B], sub_frame=2)
    assert rec.nodes["S1"].radar == SUB_B and rec.nodes["S1"].cube.shape[0] == 2
