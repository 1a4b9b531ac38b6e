"""Atomic writes keep the old file on failure and give umask permissions."""

import os
import re
import stat
import subprocess
import sys
import time

import pytest

from mmsnap_graph import FileFormatError
from mmsnap_graph._atomic import (atomic_path, recording_lock, remove_stale_temporaries,
                                  temporary_prefix)


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
    mine = tmp_path / (temporary_prefix(target) + "live.tmp")
    killed = tmp_path / (temporary_prefix(target, dead.pid) + "dead.tmp")
    old = tmp_path / ".out.json.abc123.tmp"  # the old naming, two days old
    other = tmp_path / ".other.json.99999999@x.y.tmp"
    for p in (mine, killed, old, other):
        p.write_text("partial")
    two_days = time.time() - 2 * 86400
    os.utime(old, (two_days, two_days))
    with atomic_path(target) as tmp:
        assert tmp.name.startswith(temporary_prefix(target))  # the names the test plants
        tmp.write_text("{}")
    assert target.read_text() == "{}"
    assert mine.exists() and other.exists()
    assert not killed.exists() and not old.exists()
    assert remove_stale_temporaries(target) == []


def _special_files(folder):
    """A device node (the numbers of /dev/null, made here), a FIFO, a symlink
    to each and a folder, all in ``folder``: never the machine's own /dev."""
    folder.mkdir()
    made = {}
    try:
        os.mknod(folder / "null", stat.S_IFCHR | 0o600, os.makedev(1, 3))
        made["device"] = folder / "null"
    except PermissionError:  # not root: no device node to test with
        pass
    os.mkfifo(folder / "fifo")
    made["fifo"] = folder / "fifo"
    for name, target in list(made.items()):
        (folder / f"link_{name}").symlink_to(target)
        made[f"link to {name}"] = folder / f"link_{name}"
    (folder / "dir").mkdir()
    made["directory"] = folder / "dir"
    return made


def _identity(path):
    st = os.lstat(path)
    return st.st_ino, st.st_mode, st.st_rdev


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="POSIX FIFOs and device nodes")
def test_a_device_node_a_fifo_a_link_to_them_or_a_folder_is_never_replaced(tmp_path):
    """Before: os.replace put the temporary file over a device node or a
    FIFO (as root, `-o /dev/null` replaced the machine's /dev/null)."""
    from mmsnap_graph._atomic import check_output_path

    made = _special_files(tmp_path / "scratch")
    before = {name: _identity(p) for name, p in made.items()}
    kinds = {"device": "a character device", "fifo": "a FIFO"}
    for name, path in made.items():
        with pytest.raises(FileFormatError, match="directory" if name == "directory" else
                           kinds[name.rsplit(" ", 1)[-1]] + ", not a regular file") as info:
            with atomic_path(path) as tmp:
                tmp.write_text("written")
        assert str(path) in str(info.value)
        if name.startswith("link"):
            assert "symbolic link to" in str(info.value)
        with pytest.raises(FileFormatError, match=str(path)):
            check_output_path(path)
        with pytest.raises(FileFormatError, match=f"cannot lock {os.path.realpath(path)}"):
            with recording_lock(path):
                pass
    assert {name: _identity(p) for name, p in made.items()} == before
    assert sorted(p.name for p in (tmp_path / "scratch").iterdir()) == sorted(
        p.name for p in made.values())  # no temporary file, no lock file left


def test_a_file_swapped_for_a_fifo_during_the_write_is_kept(tmp_path):
    dst = tmp_path / "out.json"
    with pytest.raises(FileFormatError, match="became a FIFO while it was written"):
        with atomic_path(dst) as tmp:
            tmp.write_text("{}")
            os.mkfifo(dst)
    assert stat.S_ISFIFO(os.lstat(dst).st_mode)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.json"]


def test_a_planted_lock_symlink_is_refused_not_followed(tmp_path):
    """Before: the lock's open(lock, "a+") followed a planted `.rec.h5.lock`
    symlink and created the file it names."""
    rec = tmp_path / "rec.h5"
    rec.write_bytes(b"x")
    victim = tmp_path / "elsewhere" / "victim"
    victim.parent.mkdir()
    (tmp_path / ".rec.h5.lock").symlink_to(victim)
    with pytest.raises(FileFormatError, match=r"lock file .*\.rec\.h5\.lock is a symbolic link"):
        with recording_lock(rec, timeout_s=1):
            pass
    assert not victim.exists()
    victim.write_text("precious")  # an existing target is not truncated either
    with pytest.raises(FileFormatError, match="symbolic link"):
        with recording_lock(rec, timeout_s=1):
            pass
    assert victim.read_text() == "precious"


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="POSIX FIFOs")
def test_a_planted_lock_fifo_is_refused_without_blocking(tmp_path):
    rec = tmp_path / "rec.h5"
    rec.write_bytes(b"x")
    os.mkfifo(tmp_path / ".rec.h5.lock")
    with pytest.raises(FileFormatError, match="lock file .* is a FIFO, not a regular file"):
        with recording_lock(rec, timeout_s=1):
            pass


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="POSIX FIFOs and device nodes")
def test_the_library_writers_refuse_a_device_a_fifo_and_links_to_them(tmp_path,
                                                                      recording_b_file):
    """The writers outside the command line's options (an HDF5 recording, a
    DCA1000 capture, a figure) go through atomic_path too: each refused,
    nothing replaced."""
    import numpy as np
    from matplotlib.figure import Figure

    from mmsnap_graph.app.plots import save
    from mmsnap_graph.io import read_recording, write_recording
    from mmsnap_graph.io.ti.cfg import read_ti_cfg
    from mmsnap_graph.io.ti.dca1000 import write_dca1000_bin

    from _shared import TI_DATA

    config = read_ti_cfg(TI_DATA / "dca1000_small.cfg", board="AWR1843BOOST").configs[0]
    rec = read_recording(recording_b_file)
    writers = {
        "recording": lambda p: write_recording(p, rec, overwrite=True),
        "capture": lambda p: write_dca1000_bin(p, np.zeros((1, *config.cube_shape)), config),
        "figure": lambda p: save(Figure(figsize=(1, 1)), p),
    }
    made = _special_files(tmp_path / "scratch")
    made.pop("directory")
    before = {name: _identity(p) for name, p in made.items()}
    for writer in writers.values():
        for path in made.values():
            with pytest.raises(FileFormatError, match="not a regular file"):
                writer(path)
    assert {name: _identity(p) for name, p in made.items()} == before
    assert sorted(p.name for p in (tmp_path / "scratch").iterdir()) == sorted(
        [p.name for p in made.values()] + ["dir"])


def test_scratch_folders_of_killed_writers_are_removed_by_the_next_write(tmp_path):
    """Before: a scratch folder a kill -9 left beside the output (mmsnap
    simulate's memory-mapped cubes: gigabytes) stayed for ever; only files
    were removed."""
    from mmsnap_graph._atomic import scratch_folder

    target = tmp_path / "sim.h5"
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    left = tmp_path / (temporary_prefix(target, dead.pid) + "abc.tmp")
    (left / "inner").mkdir(parents=True)
    (left / "inner" / "cube_S1.c64").write_bytes(b"\0" * 64)
    with scratch_folder(target) as scratch:
        assert scratch.parent == tmp_path and scratch.name.startswith(".sim.h5.")
        assert not left.exists()
        (scratch / "cube").write_bytes(b"x")
        with atomic_path(target) as tmp:  # the writer's own scratch is kept meanwhile
            tmp.write_bytes(b"h5")
        assert scratch.is_dir()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["sim.h5"]


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="POSIX FIFOs and device nodes")
def test_a_stream_opens_regular_files_only_and_never_blocks(tmp_path):
    """open_regular (mmsnap live -o, a stream written as it goes): a device
    node, a FIFO with or without a reader, a link to each and a folder are
    refused at the open, without blocking and without writing into them;
    before, live opened its -o with open(path, "w"), which blocks on a FIFO
    nobody reads and writes into a device, when one took the file's place
    after the command's checks."""
    from mmsnap_graph._atomic import open_regular

    made = _special_files(tmp_path / "scratch")
    before = {name: _identity(p) for name, p in made.items()}
    reader = os.open(made["fifo"], os.O_RDONLY | os.O_NONBLOCK)  # a FIFO someone reads
    try:
        for name, path in made.items():
            with pytest.raises(FileFormatError, match=re.escape(str(path))) as info:
                open_regular(path)
            assert ("directory" if name == "directory" else "not a regular file") \
                in str(info.value), (name, info.value)
        os.close(reader)
        reader = None
        with pytest.raises(FileFormatError, match="a FIFO"):  # nobody reads it
            open_regular(made["fifo"])
    finally:
        if reader is not None:
            os.close(reader)
    assert {name: _identity(p) for name, p in made.items()} == before
    target = tmp_path / "elsewhere.jsonl"
    target.write_text("old old old\n")
    link = tmp_path / "link.jsonl"
    link.symlink_to(target)
    with open_regular(link) as out:
        out.write("new\n")
    assert target.read_text() == "new\n" and link.is_symlink()
    with open_regular(tmp_path / "new.jsonl") as out:
        out.write("x\n")
    assert (tmp_path / "new.jsonl").read_text() == "x\n"
