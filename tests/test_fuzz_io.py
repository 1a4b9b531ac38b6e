"""Property-based fuzzing of reading recordings (issue 13, "A fuzz suite"):
``read_recording`` on a damaged file raises only the project's errors
(:class:`mmsnap_graph.FileFormatError` naming what is wrong), never an h5py
or numpy exception. Derandomized examples; the known findings of issue 13 are
``xfail(strict=True)`` tests naming the finding (XPASS once fixed).
"""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mmsnap_graph import MmsnapError, read_recording
from mmsnap_graph.app.cli import main

FUZZ = settings(max_examples=80, deadline=None, derandomize=True, database=None,
                report_multiple_bugs=False, suppress_health_check=[HealthCheck.too_slow])

_names = itertools.count()


class Source(tuple):
    """(bytes of the file, folder for damaged copies), with a short repr."""

    def __repr__(self) -> str:
        return f"<recording of {len(self[0])} bytes>"


@pytest.fixture(scope="module")
def recording_bytes(tmp_path_factory) -> Source:
    """A small valid recording (2 nodes, 40 frames, centroids and point
    clouds), and a folder for the damaged copies."""
    d = tmp_path_factory.mktemp("fuzz_io")
    path = d / "good.h5"
    assert main(["simulate", "--model", "clean", "-c", "B", "-t", "random", "-n", "40", "--seed", "3",
                 "-o", str(path), "--no-progress"]) == 0
    read_recording(path)  # the undamaged file reads
    return Source((path.read_bytes(), d))


def read_damaged(data: bytes, folder: Path) -> None:
    """Write ``data`` to a fresh file and read it; a project error is fine."""
    path = folder / f"damaged_{next(_names)}.h5"
    path.write_bytes(data)
    try:
        read_recording(path)
    except MmsnapError:
        pass
    finally:
        path.unlink()


@FUZZ
@given(st.floats(0.0, 0.999))
def test_a_truncated_file_raises_only_typed_errors(recording_bytes, keep_fraction):
    data, folder = recording_bytes
    read_damaged(data[:int(len(data) * keep_fraction)], folder)


@FUZZ
@given(st.integers(0, 2**32 - 1))
def test_a_file_whose_body_is_garbage_raises_only_typed_errors(recording_bytes, seed):
    data, folder = recording_bytes
    rng = np.random.default_rng(seed)
    start = int(rng.integers(0, 512))
    garbage = rng.integers(0, 256, len(data) - start, dtype=np.uint8).tobytes()
    read_damaged(data[:start] + garbage, folder)


@FUZZ
@given(st.lists(st.tuples(st.integers(0, 2**31), st.integers(0, 7)), min_size=1, max_size=16))
def test_a_bit_flipped_file_raises_only_typed_errors(recording_bytes, flips):
    data, folder = recording_bytes
    damaged = bytearray(data)
    for position, bit in flips:
        damaged[position % len(damaged)] ^= 1 << bit
    read_damaged(bytes(damaged), folder)
