"""Property-based fuzzing of the radar chain on one cube, the DCA1000
reader and the UART reader's sub-frame fields: typed errors only, nothing merged. Derandomized, sized for CI. (The stream's and
track matching's fuzz tests are in tests/fusion/stream/test_frame_stream.py
and tests/calibration/pairwise/test_matching.py.)
"""

from __future__ import annotations

import dataclasses

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from mmsnap_graph.errors import MmsnapError
from mmsnap_graph.io import read_dca1000_bin
from mmsnap_graph.io.ti.cfg import read_ti_cfg
from mmsnap_graph.radar.chain import ChainConfig, point_cloud_of_cube

from _fuzz import FUZZ_40, SUB_FRAME_VALUES
from _shared import TI_DATA

DCA = read_ti_cfg(TI_DATA / "dca1000_small.cfg", board="AWR1843BOOST").configs[0]


@FUZZ_40
@given(st.integers(0, 2**32 - 1), st.sampled_from(["noise", "zeros", "edge", "tone"]),
       st.sampled_from([None, ChainConfig(min_range_m=0.0), ChainConfig(doppler_wraps=0)]))
def test_point_cloud_of_cube_raises_only_typed_errors(seed, kind, chain):
    rng = np.random.default_rng(seed)
    shape = DCA.cube_shape
    cube = (rng.normal(size=shape) + 1j * rng.normal(size=shape)).astype(np.complex64)
    if kind == "zeros":
        cube[:] = 0
    elif kind == "edge":
        cube.flat[rng.integers(cube.size, size=3)] = rng.choice([np.nan, np.inf, 3e38, 1e-45])
    elif kind == "tone":
        cube += 1e3 * np.exp(2j * np.pi * 0.2 * np.arange(shape[0]))[:, None, None]
    try:
        (r, w, v, snr), status = point_cloud_of_cube(cube, DCA, chain)
    except MmsnapError:
        return
    for col in (r, w, v, snr):
        assert np.all(np.isfinite(col))
    assert np.all(r >= 0) and np.all(np.abs(w) <= np.pi + 1e-9)


@FUZZ_40
@given(st.binary(max_size=3 * 4096), st.sampled_from([0, 4096]),
       st.sampled_from([None, 8192]), st.booleans())
def test_read_dca1000_raises_only_typed_errors(data, offset, stride, partial):
    import tempfile
    from pathlib import Path
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "adc_data.bin"
        path.write_bytes(data)
        try:
            cube = read_dca1000_bin(path, DCA, offset_bytes=offset, stride_bytes=stride,
                                    allow_partial_frame=partial)
        except MmsnapError:
            return
    assert cube.shape[1:] == DCA.cube_shape and np.all(np.isfinite(cube))


def test_the_sample_configuration_is_small():
    # Keeps the cube fuzzing cheap: 32 samples x 4 loops x 8 channels.
    assert DCA.cube_shape == (32, 4, 8)
    assert dataclasses.is_dataclass(DCA)


def _sub_frame_log(corrupt, rng):
    """Eight frames of distinct points; ``corrupt``: (packet, sub-frame value,
    copy) triples, each writing the value into that packet's sub-frame field
    (of a copy sent after it, or of the packet itself)."""
    from ti_encode import encode_oob_frame
    packets = [encode_oob_frame(k, rng.uniform(-2, 2, (k % 3 + 2, 3)), np.zeros(k % 3 + 2))
               for k in range(1, 9)]
    extra = {}
    for index, value, copy in corrupt:
        p = bytearray(packets[index])
        p[36:40] = value.to_bytes(4, "little")
        if copy:
            extra[index] = bytes(p)
        else:
            packets[index] = bytes(p)
    return packets, b"".join(p + extra.get(i, b"") for i, p in enumerate(packets))


@FUZZ_40
@given(st.lists(st.tuples(st.integers(0, 7), SUB_FRAME_VALUES, st.booleans()), min_size=1,
                max_size=4, unique_by=lambda t: t[0]), st.sampled_from([1, None]),
       st.integers(0, 2**32 - 1))
def test_a_corrupted_sub_frame_field_is_never_merged(corrupt, n_sub_frames, seed):
    """Sub-frame fields written with any value: a frame keeps the points of its
    one packet (never another's on top), each dropped packet is reported, and
    only project errors come out. Without the configuration (None) one
    corrupted field at a time, which the log's other frames outvote."""
    from mmsnap_graph.io.ti.uart import parse_ti_uart
    if n_sub_frames is None:
        corrupt = corrupt[:1]
    packets, data = _sub_frame_log(corrupt, np.random.default_rng(seed))
    try:
        log = parse_ti_uart(data, n_sub_frames=n_sub_frames)
    except MmsnapError:
        return
    counts = np.bincount(log.points.frame, minlength=9)
    for k in log.frame_numbers:
        assert counts[k] == k % 3 + 2, (k, counts[k])
    assert len(log.bad) >= len(corrupt) - sum(1 for _, v, copy in corrupt if not copy and v == 0)
