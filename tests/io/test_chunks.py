"""The windowed reader (mmsnap_graph.io.chunks) walks the frames present,
not their span: a gap of 10^12 frames, frame numbers near the int64 maximum
or a tiny frame period cost no more than an ordinary recording."""

from __future__ import annotations

import shutil
import time

import h5py
import numpy as np
import pytest

from mmsnap_graph.app.cli import main
from mmsnap_graph.io.chunks import open_detection_windows
from mmsnap_graph.io.fused import read_fused

BIG = 2 ** 63 - 100


@pytest.fixture(scope="module")
def base(recording_b_real_file):
    """The shared small recording (read only: the tests edit copies)."""
    return recording_b_real_file


def _edited(base, tmp_path, frames=None, period=None):
    path = tmp_path / "rec.h5"
    shutil.copy(base, path)
    with h5py.File(path, "r+") as f:
        for name in f["nodes"]:
            g = f["nodes"][name]["centroids"]
            new = frames(g["frame"][()]).astype(np.int64)
            del g["frame"]
            g["frame"] = new
        del f["truth"]
        if period is not None:
            f.attrs["frame_period_s"] = period
    return path


CASES = {
    "gap 1e12": dict(frames=lambda fr: np.where(fr >= 20, fr + 10 ** 12, fr)),
    "near int64 max": dict(frames=lambda fr: fr + BIG),
    "both ends of int64": dict(frames=lambda fr: np.where(fr >= 20, fr + BIG, fr - 2 ** 62)),
}


def test_a_tiny_frame_period_is_refused_quickly(base, tmp_path, capsys):
    # 1e-300 s is a unit mistake (below a radar's chirp): refused where the
    # recording is read, in well under a second, not fused over a huge span.
    from mmsnap_graph.errors import MmsnapError
    path = _edited(base, tmp_path, frames=lambda fr: fr, period=1e-300)
    t0 = time.monotonic()
    with pytest.raises(MmsnapError, match="frame_period_s"):
        list(open_detection_windows(path).windows(2000, margin=3))
    assert main(["fuse", str(path), "--no-progress"]) in (1, 2)
    assert "frame_period_s' must be a number in [1e-06, 3600] s, got 1e-300" \
        in capsys.readouterr().err
    assert time.monotonic() - t0 < 5
    assert [p.name for p in tmp_path.iterdir()] == ["rec.h5"]  # no lock or temporary left


@pytest.mark.parametrize("case", sorted(CASES))
def test_windows_are_bounded_by_the_frames_present(base, tmp_path, case):
    windows = open_detection_windows(_edited(base, tmp_path, **CASES[case]))
    t0 = time.monotonic()
    spans = list(windows.windows(2000, margin=3))
    assert time.monotonic() - t0 < 0.5
    assert 1 <= len(spans) <= 2
    frames = np.unique(np.concatenate([windows.read(a, b)[1]["S1"] for a, b in spans]))
    assert frames.size == windows.n_rows["S1"]  # every row in exactly one window


def test_windows_still_tile_a_contiguous_recording(base):
    windows = open_detection_windows(base)
    assert list(windows.windows(16)) == [(0, 16), (16, 32), (32, 40)]
    assert list(windows.windows(16, margin=2)) == [(-2, 14), (14, 30), (30, 42)]


@pytest.mark.parametrize("case", sorted(CASES))
def test_fuse_of_a_sparse_frame_span_is_quick(base, tmp_path, capsys, case):
    path = _edited(base, tmp_path, **CASES[case])
    t0 = time.monotonic()
    assert main(["fuse", str(path), "--no-progress"]) == 0, capsys.readouterr().err
    assert time.monotonic() - t0 < 10
    fused = read_fused(path)
    assert len(fused) > 0 and np.unique(fused.frame).size == 40
    assert [p.name for p in tmp_path.iterdir()] == ["rec.h5"]  # no lock or temporary left


def test_the_scratch_of_a_killed_fuse_is_beside_the_output_and_removed_next_time(base,
                                                                                  tmp_path):
    """Before: `kill -9` of a fuse left `$TMPDIR/mmsnap_fused_*` folders that
    nothing removed. Now the scratch is beside the output, named as the
    writers' temporary files, and the next write of that file removes it."""
    import os
    import subprocess
    import sys

    from mmsnap_graph.io.chunks import fused_writer

    work = tmp_path / "work"
    work.mkdir()
    rec = work / "rec.h5"
    shutil.copy(base, rec)
    tmpdir = tmp_path / "tmpdir"
    tmpdir.mkdir()
    code = ("import os, signal, sys\nfrom mmsnap_graph.io.chunks import fused_writer\n"
            "with fused_writer(sys.argv[1]) as w:\n"
            "    os.kill(os.getpid(), signal.SIGKILL)\n")
    proc = subprocess.run([sys.executable, "-c", code, str(rec)], capture_output=True,
                          env={**os.environ, "TMPDIR": str(tmpdir)}, timeout=120)
    assert proc.returncode == -9, proc.stderr
    assert list(tmpdir.iterdir()) == []
    left = sorted(p.name for p in work.iterdir() if p.name != "rec.h5")
    assert any(p.is_dir() for p in work.iterdir() if p.name.endswith(".tmp")), left
    with fused_writer(rec):
        pass
    assert sorted(p.name for p in work.iterdir()) == ["rec.h5"]


def test_a_window_without_person_ids_reads_as_no_person(base, fused_b_map, tmp_path):
    """A window appended without ``track_id`` before one with it: its rows
    read -1 (no person), not 0 (the first person's id)."""
    import dataclasses

    from mmsnap_graph.io.chunks import fused_writer

    path = tmp_path / "rec.h5"
    shutil.copy(base, path)
    assert (fused_b_map.track_id == 0).any()
    with fused_writer(path) as writer:
        writer.append(dataclasses.replace(fused_b_map, track_id=None))
        writer.append(fused_b_map)
    back = read_fused(path).track_id
    n = len(fused_b_map)
    np.testing.assert_array_equal(back[:n], -1)
    np.testing.assert_array_equal(back[n:], fused_b_map.track_id)
