"""Property-based fuzzing of the radar chain on one cube, the DCA1000
reader and the UART reader's sub-frame fields: typed errors only, nothing merged. Derandomized, sized for CI. (The stream's and
track matching's fuzz tests are in tests/fusion/stream/test_frame_stream.py
and tests/calibration/pairwise/test_matching.py.)
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from mmsnap_graph.errors import MmsnapError
from mmsnap_graph.io import read_dca1000_bin
from mmsnap_graph.io.ti.cfg import read_ti_cfg
from mmsnap_graph.radar.chain import ChainConfig, point_cloud_of_cube

from _fuzz import FUZZ_40, SUB_FRAME_VALUES
from _shared import TI_DATA

DCA = read_ti_cfg(TI_DATA / "dca1000_small.cfg", board="AWR1843BOOST").configs[0]
ADVANCED = read_ti_cfg(TI_DATA / "dca1000_small.cfg", board="AWR1843BOOST")


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


# The public readers of files, each fuzzed somewhere: a reader added to a
# module's __all__ without a fuzz test fails test_every_public_reader_is_fuzzed.

#: reader -> the fuzz test (file::name) that feeds it damaged input.
FUZZED_READERS = {
    "read_recording": "tests/io/test_hdf5.py::test_a_bit_flipped_file_raises_only_typed_errors",
    "open_recording_file": "tests/io/test_hdf5.py::test_a_bit_flipped_file_raises_only_typed_errors",
    "iter_cubes": "tests/io/test_hdf5.py::test_a_bit_flipped_file_raises_only_typed_errors",
    "read_cube_frames": "tests/io/test_hdf5.py::test_a_bit_flipped_file_raises_only_typed_errors",
    "read_dca1000_bin": "tests/test_fuzz_entry_points.py::test_read_dca1000_raises_only_typed_errors",
    "iter_dca1000_frames":
        "tests/test_fuzz_entry_points.py::test_read_dca1000_raises_only_typed_errors",
    "read_dca1000_sub_frame":
        "tests/test_fuzz_entry_points.py::test_damaged_files_give_project_errors_only",
    "parse_ti_cfg": "tests/io/ti/test_cfg.py::test_parser_raises_only_project_errors",
    "read_ti_cfg": "tests/io/ti/test_cfg.py::test_seeded_mutations_raise_only_project_errors",
    "read_boundary_boxes":
        "tests/test_fuzz_entry_points.py::test_damaged_files_give_project_errors_only",
    "read_studio_json": "tests/test_fuzz_entry_points.py::test_damaged_files_give_project_errors_only",
    "parse_ti_uart": "tests/io/ti/test_uart.py::test_reader_raises_only_project_errors",
    "read_ti_uart": "tests/io/ti/test_uart.py::test_reader_raises_only_project_errors",
    "UartStreamParser": "tests/io/ti/serial/test_stream.py::test_any_read_sizes_give_the_same_packets",
    "read_point_table": "tests/io/ti/test_point_table.py::test_csv_reader_raises_only_project_errors",
    "read_point_tables":
        "tests/io/ti/test_point_table.py::test_stray_frame_numbers_never_move_a_nodes_clock",
    "read_rosbag": "tests/test_fuzz_entry_points.py::test_damaged_files_give_project_errors_only",
    "read_fused": "tests/test_fuzz_entry_points.py::test_damaged_files_give_project_errors_only",
    "read_noise": "tests/test_fuzz_entry_points.py::test_damaged_files_give_project_errors_only",
    "read_range_offset":
        "tests/test_fuzz_entry_points.py::test_damaged_files_give_project_errors_only",
    "read_calibration": "tests/test_fuzz_entry_points.py::test_damaged_files_give_project_errors_only",
    "read_calibration_json":
        "tests/io/test_calibration.py::test_calibration_json_seeded_mutations_raise_only_calibration_errors",
    "read_process_config": "tests/app/test_config_file.py::test_toml_mutations_are_rejected_or_processed",
    "read_matching_config":
        "tests/app/test_config_file.py::test_toml_mutations_are_rejected_or_processed",
    "read_fuse_table": "tests/test_fuzz_entry_points.py::test_damaged_files_give_project_errors_only",
    "read_boards_toml": "tests/test_fuzz_entry_points.py::test_damaged_files_give_project_errors_only",
    "parse_board": "tests/test_fuzz_entry_points.py::test_damaged_files_give_project_errors_only",
}
#: Names the rule below matches that read no file of the user's.
NOT_READERS = {
    "read_guard": "the readers' error guard (io.guard), fuzzed through each of them",
    "open_for_reading": "the guard's open, fuzzed through each reader",
    "open_group": "the guard's group open, fuzzed through each reader",
    "open_port": "a serial port (hardware), not a file",
    "open_detection_windows": "read_recording's windows (tests/app/test_chunked_fuse.py)",
}


def _public_readers() -> dict[str, str]:
    """Every public name of mmsnap_graph.io (and the TOML readers of
    app.config_file) that reads or parses a file or its bytes."""
    import importlib
    import inspect
    import pkgutil
    import re

    import mmsnap_graph.io

    found = {}
    modules = [i.name for i in pkgutil.walk_packages(mmsnap_graph.io.__path__, "mmsnap_graph.io.")]
    for name in ["mmsnap_graph.io", *modules, "mmsnap_graph.app.config_file"]:
        module = importlib.import_module(name)
        for attr in getattr(module, "__all__", ()):
            obj = getattr(module, attr, None)
            if (inspect.isfunction(obj) or inspect.isclass(obj)) \
                    and re.match(r"(read|parse|iter|open)_|.*Parser$", attr):
                found.setdefault(attr, obj.__module__)
    return found


def test_every_public_reader_is_fuzzed():
    from _shared import ROOT

    readers = _public_readers()
    missing = sorted(set(readers) - set(FUZZED_READERS) - set(NOT_READERS))
    assert missing == [], f"public readers without a fuzz test: {missing}"
    assert len(readers) >= 30, sorted(readers)
    for reader, where in FUZZED_READERS.items():
        path, _, test = where.partition("::")
        text = (ROOT / path).read_text()
        assert not test or f"def {test}(" in text, (reader, where)


@pytest.fixture(scope="module")
def damaged_inputs(tmp_path_factory, recording_b_file):
    """Good inputs of the readers the other fuzz tests do not reach: a
    recording with /calibration, /noise and /fused, a Studio JSON, a
    [fuse] TOML file, a boards TOML file, a DCA1000 advanced-frame capture."""
    from mmsnap_graph.app.cli import main

    folder = tmp_path_factory.mktemp("damaged_inputs")
    rec = folder / "rec.h5"
    rec.write_bytes(recording_b_file.read_bytes())
    assert main(["calibrate", str(rec), "--no-progress"]) in (0, 1)
    assert main(["fuse", str(rec), "--no-progress"]) == 0
    boards = folder / "boards.toml"
    boards.write_text('[boards.S1]\ncli = "/nowhere/ttyACM0"\ndata = "/nowhere/ttyACM1"\n'
                      '[boards.S2]\nusb = "R0091"\n')
    from _rosbags import write_bag
    bag = write_bag(folder / "one.bag", {"/radar": [
        (10**9 + k * 10**8, 10**9 + k * 10**8, [[0.5, 2 + 0.05 * k, 0.0]], [0.1], [20.0])
        for k in range(10)]}, ros=1)
    boxes = folder / "boxes.cfg"
    boxes.write_text((TI_DATA / "iwr1843_oob.cfg").read_text()
                     + "boundaryBox -4 4 0 8 0 3\nstaticBoundaryBox -3 3 0.5 7 0 3\n")
    fuse = folder / "fuse.toml"
    fuse.write_text("[fuse]\ngate = 9.21\nbounds = [-1.0, 6.0, -1.0, 8.0]\n")
    return {"rec": rec.read_bytes(), "studio": (TI_DATA / "dca1000_fast.mmwave.json").read_bytes(),
            "boards": boards.read_bytes(), "fuse": fuse.read_bytes(),
            "adv": (TI_DATA / "dca1000_small.bin").read_bytes(), "bag": Path(bag).read_bytes(),
            "boxes": boxes.read_bytes()}


def _damage(data: bytes, rng, how: str) -> bytes:
    if how == "cut":
        return data[:int(rng.integers(0, len(data)))]
    damaged = bytearray(data)
    for _ in range(int(rng.integers(1, 12))):
        damaged[int(rng.integers(0, len(data)))] ^= 1 << int(rng.integers(0, 8))
    return bytes(damaged)


@FUZZ_40
@given(st.integers(0, 2**32 - 1), st.sampled_from(["cut", "flip"]),
       st.sampled_from(["read_fused", "read_noise", "read_range_offset", "read_calibration",
                        "read_studio_json", "read_fuse_table", "read_boards_toml",
                        "read_dca1000_sub_frame", "parse_board", "read_rosbag",
                        "read_boundary_boxes"]))
def test_damaged_files_give_project_errors_only(damaged_inputs, tmp_path_factory, seed, how,
                                                reader):
    """A good file cut short or with bits flipped (seeded), read by each
    public reader no other fuzz test reaches: a result or a project error,
    never another exception."""
    from mmsnap_graph.app.config_file import read_fuse_table
    from mmsnap_graph.io.calibration import read_calibration
    from mmsnap_graph.io.fused import read_fused
    from mmsnap_graph.io.noise import read_noise, read_range_offset
    from mmsnap_graph.io.ti.cfg import read_boundary_boxes, read_studio_json
    from mmsnap_graph.io.ti.rosbag import read_rosbag
    from mmsnap_graph.io.ti.dca1000 import read_dca1000_sub_frame
    from mmsnap_graph.io.ti.serial.boards import parse_board, read_boards_toml

    rng = np.random.default_rng(seed)
    source, call = {
        "read_fused": ("rec", read_fused), "read_noise": ("rec", read_noise),
        "read_range_offset": ("rec", read_range_offset),
        "read_calibration": ("rec", read_calibration),
        "read_studio_json": ("studio", lambda p: read_studio_json(p, board="AWR1843BOOST")),
        "read_fuse_table": ("fuse", read_fuse_table), "read_boards_toml": ("boards",
                                                                          read_boards_toml),
        "read_dca1000_sub_frame": ("adv", lambda p: read_dca1000_sub_frame(
            p, ADVANCED.configs, 1, allow_partial_frame=True)),
        "parse_board": ("boards", lambda p: parse_board(
            p.read_bytes().decode("utf-8", "replace").splitlines()[-1])),
        "read_rosbag": ("bag", lambda p: read_rosbag(p, {"/radar": "S1"})),
        "read_boundary_boxes": ("boxes", read_boundary_boxes),
    }[reader]
    path = tmp_path_factory.mktemp("d") / ("damaged.bag" if source == "bag" else
                                           f"damaged.{source}")
    path.write_bytes(_damage(damaged_inputs[source], rng, how))
    try:
        call(path)
    except MmsnapError:
        pass
