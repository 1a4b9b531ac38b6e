"""Bad files and bad output paths through the CLI verbs (issue 13, "A fuzz
suite": a bad-file suite across every verb). A verb given a damaged
recording must exit non-zero with a one-line error (``mmsnap VERB: error:
...``), never a traceback. Known findings of issue 13 are
``xfail(strict=True)`` tests naming the finding (XPASS once fixed).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mmsnap_graph.app.cli import main

#: Verbs that read one recording, with the options that keep them quiet.
VERBS = {
    "process": ["--no-progress"],
    "calibrate": [],
    "fuse": ["--no-progress"],
    "evaluate": [],
}


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, Path]:
    """A good recording (known poses, with truth) and damaged copies of it."""
    d = tmp_path_factory.mktemp("fuzz_cli")
    good = d / "good.h5"
    assert main(["simulate", "--model", "clean", "-c", "B", "-t", "random", "-n", "60", "-l", "centroids",
                 "--seed", "5", "--known-poses", "-o", str(good), "--no-progress"]) == 0
    data = good.read_bytes()
    out = {"good": good}
    out["truncated"] = d / "truncated.h5"
    out["truncated"].write_bytes(data[: len(data) // 3])
    out["empty"] = d / "empty.h5"
    out["empty"].write_bytes(b"")
    out["not_hdf5"] = d / "not_hdf5.h5"
    out["not_hdf5"].write_bytes(b"mmsnap" * 1000)
    garbage = bytearray(data)
    garbage[2048:] = np.random.default_rng(1).integers(0, 256, len(data) - 2048,
                                                       dtype=np.uint8).tobytes()
    out["garbage_body"] = d / "garbage_body.h5"
    out["garbage_body"].write_bytes(bytes(garbage))
    flipped = bytearray(data)
    flipped[17] ^= 1  # found by tests/test_fuzz_io.py: h5py raises RuntimeError
    out["bit_flipped"] = d / "bit_flipped.h5"
    out["bit_flipped"].write_bytes(bytes(flipped))
    return out


def run_verb(verb: str, path: Path, capsys) -> tuple[int, list[str]]:
    code = main([verb, str(path), *VERBS[verb]])
    return code, capsys.readouterr().err.strip().splitlines()


@pytest.mark.parametrize("verb", sorted(VERBS))
@pytest.mark.parametrize("damage", ["truncated", "empty", "not_hdf5", "garbage_body"])
def test_a_damaged_recording_gives_a_one_line_error(files, capsys, verb, damage):
    code, err = run_verb(verb, files[damage], capsys)
    assert code == 1
    assert len(err) == 1 and err[0].startswith(f"mmsnap {verb}: error: ")


@pytest.mark.parametrize("verb", sorted(VERBS))
def test_a_bit_flipped_recording_gives_a_one_line_error(files, capsys, verb):
    code, err = run_verb(verb, files["bit_flipped"], capsys)
    assert code == 1 and len(err) == 1


@pytest.mark.parametrize("verb", sorted(VERBS))
def test_the_error_for_a_damaged_recording_names_the_file(files, capsys, verb):
    code, err = run_verb(verb, files["garbage_body"], capsys)
    assert code == 1 and "garbage_body.h5" in err[0]


@pytest.mark.parametrize("argv", [
    ["process", "{good}", "-o", "{dir}", "--no-progress"],
    ["fuse", "{good}", "-o", "{dir}", "--no-progress"],
    ["calibrate", "{good}", "--no-write", "--json-out", "{dir}"],
    ["simulate", "-n", "20", "-l", "centroids", "-o", "{dir}", "--overwrite", "--no-progress"],
])
def test_an_output_path_that_is_a_directory_gives_a_one_line_error(files, tmp_path, capsys,
                                                                    argv):
    argv = [a.format(good=files["good"], dir=tmp_path) for a in argv]
    assert main(argv) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1
