"""Regression tests of issue 13, "Reliability: what broke", for files: two
writers at once lose nothing (two real processes), temporary files of killed
writers are cleaned up, a directory as output is a one-line error."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

from mmsnap_graph import read_recording
from mmsnap_graph._atomic import atomic_path, recording_lock, remove_stale_temporaries
from mmsnap_graph.app.cli import main
from mmsnap_graph.errors import FileFormatError
from mmsnap_graph.io.calibration import read_calibration


def mmsnap(*argv: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "mmsnap_graph", *argv],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def simulated(path: Path, n_frames: int) -> Path:
    assert main(["simulate", "--model", "clean", "-c", "B", "-t", "random", "-n", str(n_frames), "-l",
                 "centroids", "--seed", "2", "-o", str(path), "--no-progress"]) == 0
    return path


@pytest.fixture()
def recording(tmp_path) -> Path:
    return simulated(tmp_path / "rec.h5", 300)


@pytest.mark.slow
def test_process_and_calibrate_at_once_keep_both_updates(tmp_path):
    """Before: each rewrote the file from the copy it read at its start; the
    one finishing last silently dropped the other's update (on main c862145
    with 2000 frames: /calibration written, the node poses gone)."""
    recording = simulated(tmp_path / "rec.h5", 2000)
    before = read_recording(recording)
    assert all(before.nodes[n].tracks is None for n in before.node_names)
    procs = [mmsnap("process", str(recording), "--centroids-only", "--no-progress"),
             mmsnap("calibrate", str(recording), "--method", "pose_graph", "--source",
                    "centroids")]
    outs = [p.communicate(timeout=600) for p in procs]
    assert [p.returncode for p in procs] == [0, 0], outs
    after = read_recording(recording)
    cal = read_calibration(recording)
    for name in after.node_names:
        assert after.nodes[name].tracks is not None, f"{name}: process's tracks were lost"
        if name in cal.poses:
            np.testing.assert_allclose(after.nodes[name].pose, cal.poses[name],
                                       err_msg=f"{name}: calibrate's pose was lost")
    assert len(cal.poses) >= 2
    assert not list(recording.parent.glob(".rec.h5.*")), "lock or temporary files left"


def test_a_second_writer_waits_for_the_lock(recording):
    """A process holding the lock makes `mmsnap process` wait, not interleave."""
    holder = subprocess.Popen(
        [sys.executable, "-c",
         "import sys, time; from mmsnap_graph._atomic import recording_lock\n"
         f"with recording_lock({str(recording)!r}):\n"
         "    print('locked', flush=True); time.sleep(3)\n"],
        stdout=subprocess.PIPE, text=True)
    assert holder.stdout.readline().strip() == "locked"
    t0 = time.monotonic()
    proc = mmsnap("process", str(recording), "--centroids-only", "--no-progress")
    out, err = proc.communicate(timeout=600)
    holder.wait(timeout=60)
    assert proc.returncode == 0, err
    assert time.monotonic() - t0 > 1.5  # it waited for the holder
    with h5py.File(recording, "r") as f:
        assert "tracks" in f["nodes/S1"]


def test_the_lock_is_reentrant_and_times_out_naming_the_file(tmp_path):
    path = tmp_path / "x.h5"
    with recording_lock(path):
        with recording_lock(path):  # the same process: no deadlock
            pass
        other = subprocess.run(
            [sys.executable, "-c",
             "from mmsnap_graph._atomic import recording_lock\n"
             f"with recording_lock({str(path)!r}, timeout_s=0.3): pass\n"],
            capture_output=True, text=True, timeout=120)
        assert other.returncode != 0 and "x.h5 is locked" in other.stderr
    assert not (tmp_path / ".x.h5.lock").exists()


def test_stale_temporaries_of_killed_writers_are_removed(tmp_path):
    """Before: `.name.*.tmp` files of a kill -9 stayed forever."""
    target = tmp_path / "out.json"
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    host = __import__("mmsnap_graph._atomic", fromlist=["x"])._HOST
    mine = tmp_path / f".out.json.{os.getpid()}@{host}.live.tmp"
    killed = tmp_path / f".out.json.{dead.pid}@{host}.dead.tmp"
    old = tmp_path / ".out.json.abc123.tmp"  # the old naming, two days old
    other = tmp_path / ".other.json.99999999@x.y.tmp"
    for p in (mine, killed, old, other):
        p.write_text("partial")
    two_days = time.time() - 2 * 86400
    os.utime(old, (two_days, two_days))
    with atomic_path(target) as tmp:
        tmp.write_text("{}")
    assert target.read_text() == "{}"
    assert mine.exists() and other.exists()
    assert not killed.exists() and not old.exists()
    assert remove_stale_temporaries(target) == []


def test_a_killed_write_leaves_a_temporary_that_the_next_write_removes(recording):
    code = ("import os\nfrom mmsnap_graph._atomic import atomic_path\n"
            f"with atomic_path({str(recording)!r}) as tmp:\n"
            "    tmp.write_bytes(b'x' * 1000)\n    os._exit(9)\n")
    assert subprocess.run([sys.executable, "-c", code], timeout=120).returncode == 9
    assert len(list(recording.parent.glob(".rec.h5.*.tmp"))) == 1
    assert main(["process", str(recording), "--centroids-only", "--no-progress"]) == 0
    assert not list(recording.parent.glob(".rec.h5.*.tmp"))


def test_an_output_folder_is_refused_before_any_work(recording, tmp_path):
    with pytest.raises(FileFormatError, match="is a directory"):
        with atomic_path(tmp_path):
            pass
    for argv in (["process", str(recording), "-o", str(tmp_path)],
                 ["calibrate", str(recording), "--no-write", "--json-out", str(tmp_path)],
                 ["fuse", str(recording), "-o", str(tmp_path)]):
        assert main(argv) == 2
