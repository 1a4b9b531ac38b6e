"""Atomic writes keep the old file on failure and give umask permissions."""

import os
import stat

import pytest

from mmsnap_graph import FileFormatError
from mmsnap_graph._atomic import atomic_path


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
