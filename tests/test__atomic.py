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
