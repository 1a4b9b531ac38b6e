"""Atomic writes keep the old file on failure and give umask permissions."""

import os
import stat
import subprocess
import sys
import time

import pytest

from mmsnap_graph import FileFormatError
from mmsnap_graph._atomic import atomic_path, recording_lock, remove_stale_temporaries


def test_success_replaces_file_with_umask_permissions(tmp_path):
    dst = tmp_path / "out.bin"
    dst.write_bytes(b"old")
    old_mask = os.umask(0o022)
    try:
        with atomic_path(dst) as tmp:
            assert tmp.parent == tmp_path and tmp != dst
            tmp.write_bytes(b"new")
    finally:
        os.umask(old_mask)
    assert dst.read_bytes() == b"new"
    assert stat.S_IMODE(dst.stat().st_mode) == 0o644
    assert [p.name for p in tmp_path.iterdir()] == ["out.bin"]


def test_failure_keeps_old_file_and_removes_temporary(tmp_path):
    dst = tmp_path / "out.bin"
    dst.write_bytes(b"old")
    with pytest.raises(RuntimeError, match="boom"):
        with atomic_path(dst) as tmp:
            tmp.write_bytes(b"half")
            raise RuntimeError("boom")
    assert dst.read_bytes() == b"old"
    assert [p.name for p in tmp_path.iterdir()] == ["out.bin"]


def test_missing_folder_is_a_named_error(tmp_path):
    with pytest.raises(FileFormatError, match="does not exist"):
        with atomic_path(tmp_path / "nope" / "x.h5"):
            pass


def test_a_write_through_a_symlink_replaces_the_file_it_names(tmp_path):
    (tmp_path / "data").mkdir()
    target = tmp_path / "data" / "rec.bin"
    target.write_bytes(b"old")
    link = tmp_path / "link.bin"
    link.symlink_to(target)
    with atomic_path(link) as tmp:
        assert tmp.parent == target.parent
        tmp.write_bytes(b"new")
    assert link.is_symlink() and os.readlink(link) == str(target)
    assert target.read_bytes() == b"new"


def test_every_name_of_a_file_takes_the_same_lock(tmp_path):
    import subprocess
    import sys

    from mmsnap_graph._atomic import recording_lock

    target = tmp_path / "rec.h5"
    target.write_bytes(b"x")
    link = tmp_path / "other.h5"
    link.symlink_to(target)
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys, time; from mmsnap_graph._atomic import recording_lock\n"
         f"with recording_lock({str(target)!r}):\n print('held', flush=True); time.sleep(30)"],
        stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(FileFormatError, match="locked by another process"):
            with recording_lock(link, timeout_s=0.2):
                pass
    finally:
        holder.kill()
        holder.wait()
    with recording_lock(link, timeout_s=5):  # a killed holder's lock is free again
        pass


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
