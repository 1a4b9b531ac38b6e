"""Import of DCA1000 / mmWave Studio raw captures (layout: mmsnap_graph.io.dca1000)."""

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
    with pytest.raises(FileFormatError, match="less than one frame"):
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
