"""``mmsnap demo``: its arguments, its exit codes and its outputs."""

from __future__ import annotations

import shutil

import pytest
from hypothesis import given, strategies as st

from mmsnap_graph.app.cli import main

from _fuzz import CLI_FUZZ, one_line_data_error
from _shared import DATA


@pytest.fixture(scope="module")
def sample(tmp_path_factory):
    d = tmp_path_factory.mktemp("fuzz_more")
    path = d / "config_B_straight.h5"
    shutil.copy(DATA / "config_B_straight.h5", path)
    return path.read_bytes()


@CLI_FUZZ
@given(cut=st.floats(0.0, 0.95), flips=st.lists(st.tuples(st.integers(0, 4095),
                                                           st.integers(0, 7)), max_size=3))
def test_demo_on_a_damaged_sample_exits_1_naming_it(sample, tmp_path_factory, capsys, cut, flips):
    d = tmp_path_factory.mktemp("demo_data")
    data = bytearray(sample[: max(int(len(sample) * cut), 0)]) if cut > 0.01 else bytearray(sample)
    for at, bit in flips:
        if at < len(data):
            data[at] ^= 1 << bit
    if cut <= 0.01 and not flips:
        data = bytearray(b"not a recording")
    (d / "config_B_straight.h5").write_bytes(bytes(data))
    code = main(["demo", "--data", str(d), "-c", "B", "-n", "20", "--cube-frames", "0",
                 "--no-figures", "--no-progress", "--out", str(d / "out")])
    err = capsys.readouterr().err.strip().splitlines()
    if code == 0:  # a flip that hit nothing the demo reads
        return
    one_line_data_error(code, err, "config_B_straight.h5")
