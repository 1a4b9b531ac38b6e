"""Issue 13 findings whose regression tests the audit found missing:

- "Corrupted files give tracebacks in every verb": the bad-file suites
  (test_fuzz_cli, test_exit_codes) predate `mmsnap noise` and `mmsnap
  monitor`; both are held here to the same one-line error naming the file.
- "calibrate holds two full copies on disk at once": `mmsnap calibrate`
  writes the poses, /calibration and /noise with at most one temporary copy
  of the recording beside it at any time.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from mmsnap_graph.app.cli import main


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("audit13")
    good = d / "good.h5"
    assert main(["simulate", "--model", "clean", "-c", "B", "-t", "random", "-n", "60", "-l", "centroids",
                 "--seed", "5", "--known-poses", "-o", str(good), "--no-progress"]) == 0
    data = good.read_bytes()
    out = {"good": good, "missing": d / "missing.h5"}
    out["truncated"] = d / "truncated.h5"
    out["truncated"].write_bytes(data[: len(data) // 2])
    out["not_hdf5"] = d / "not_hdf5.h5"
    out["not_hdf5"].write_bytes(b"not an HDF5 file\n" * 100)
    flipped = bytearray(data)
    flipped[17] ^= 1                      # h5py raises RuntimeError (test_fuzz_cli)
    out["bit_flipped"] = d / "bit_flipped.h5"
    out["bit_flipped"].write_bytes(bytes(flipped))
    return out


@pytest.mark.parametrize("verb", ["noise", "monitor"])
@pytest.mark.parametrize("damage", ["missing", "truncated", "not_hdf5", "bit_flipped"])
def test_noise_and_monitor_on_a_bad_file_exit_1_with_one_line_naming_it(files, capsys, verb,
                                                                         damage):
    code = main([verb, str(files[damage])])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1
    assert len(err) == 1 and err[0].startswith(f"mmsnap {verb}: error: ")
    assert files[damage].name in err[0]


def test_calibrate_keeps_at_most_one_temporary_copy_on_disk(files, tmp_path, monkeypatch):
    rec = tmp_path / "rec.h5"
    rec.write_bytes(files["good"].read_bytes())
    size = rec.stat().st_size
    seen = []
    real_replace = os.replace

    def spy(src, dst, *args, **kwargs):
        # At the moment a finished temporary replaces its target, every
        # temporary copy of the recording is on disk.
        temps = [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]
        seen.append((len(temps), sum(p.stat().st_size for p in temps)))
        return real_replace(src, dst, *args, **kwargs)

    monkeypatch.setattr(os, "replace", spy)
    assert main(["calibrate", str(rec)]) == 0
    assert seen, "calibrate wrote no temporary copy"
    assert max(n for n, _ in seen) == 1
    assert max(b for _, b in seen) < 2 * size
