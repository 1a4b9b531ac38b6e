"""Atomic file writes and the recording lock: the one place that knows how
(design: nothing is lost).

A file is written to a temporary name in the destination folder and renamed
over the destination only once complete, so a crash or an error never leaves
a half-written file under the real name. The new file gets the permissions an
ordinary ``open(path, "w")`` would give (``0o666`` less the umask), not the
``0o600`` of ``tempfile.mkstemp``.

Only regular files are written: a destination that is (or, through a
symlink, names) a device node, a FIFO, a socket or a folder is refused
(:class:`~mmsnap_graph.errors.FileFormatError` naming it and what it is),
never renamed over nor written into; run as root, a rename over ``-o
/dev/null`` would replace the machine's ``/dev/null``. Standard output is
reached by each command's own form (``--json``, ``mmsnap export`` without
``-o``), not by ``/dev/stdout``. A stream written as it goes (``mmsnap live -o``)
is opened by :func:`open_regular`, which refuses the same. A symlink to a regular file is followed: the
file it names is replaced, the link stays.

Temporary files are named ``.<name>.<pid>@<host>.<random>.tmp``, and so are
the scratch folders of long writes (:func:`scratch_folder`). A writer
killed with ``kill -9`` cannot remove its own; the next write of the same
file removes the stale ones (:func:`remove_stale_temporaries`): those of a
process of this host that no longer runs, and any older than
:data:`STALE_TMP_AGE_S`.

:func:`recording_lock` serialises the read-modify-write cycles of several
processes on one file (``mmsnap process`` and ``mmsnap calibrate`` at once):
an advisory ``fcntl.flock`` on a lock file ``.<name>.lock`` beside it,
removed by its holder when done. It is
re-entrant within a process (a command holding it may call writers that take
it again). Where ``fcntl`` is missing (Windows) it does nothing. The lock
file is opened with ``O_NOFOLLOW`` (and ``O_EXCL`` when new): a planted
``.<name>.lock`` symlink is refused, never followed.
"""

from __future__ import annotations

import contextlib
import errno
import logging
import os
import re
import shutil
import socket
import stat
import tempfile
import threading
import time
from pathlib import Path
from typing import Iterator

from .errors import FileFormatError

try:  # POSIX only; without it the lock is a no-op (module docstring)
    import fcntl
except ImportError:  # pragma: no cover - Windows
    fcntl = None

__all__ = ["atomic_path", "check_output_path", "file_kind", "open_regular", "recording_lock",
           "refuse_existing", "remove_stale_temporaries", "scratch_folder", "temporary_prefix",
           "STALE_TMP_AGE_S", "LOCK_TIMEOUT_S"]

#: A temporary file of a writer on another host (or of unknown origin) older
#: than this (s) is taken as left by a killed writer and removed.
STALE_TMP_AGE_S = 24 * 3600.0
#: Seconds :func:`recording_lock` waits for another process's lock.
LOCK_TIMEOUT_S = 600.0

_log = logging.getLogger("mmsnap_graph")
_HOST = re.sub(r"[^A-Za-z0-9_-]", "_", socket.gethostname())[:40] or "host"
_TMP_OWNER = re.compile(r"\.(\d+)@([A-Za-z0-9_-]+)\.[^.]+\.tmp$")
_held: dict[str, list] = {}  # real path of a lock file -> [open file, depth]
_held_guard = threading.Lock()


def temporary_prefix(path: str | os.PathLike, pid: int | None = None) -> str:
    """The start ``.<name>.<pid>@<host>.`` of the temporary files and scratch
    folders a writer of ``path`` in process ``pid`` (default: this one)
    names beside it (module docstring); what :func:`remove_stale_temporaries`
    reads back to tell a dead writer's leftovers from a live one's."""
    return f".{Path(path).name}.{os.getpid() if pid is None else int(pid)}@{_HOST}."


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def file_kind(mode: int) -> str:
    """What a file of ``st_mode`` ``mode`` is, in words ("a FIFO", ...)."""
    for test, name in ((stat.S_ISREG, "a regular file"), (stat.S_ISDIR, "a directory"),
                       (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                       (stat.S_ISFIFO, "a FIFO"), (stat.S_ISSOCK, "a socket"),
                       (stat.S_ISLNK, "a symbolic link")):
        if test(mode):
            return name
    return "not a regular file"


def _refuse_special(path: Path, action: str) -> None:
    """:class:`FileFormatError` when ``path`` (through symlinks) exists and
    is not a regular file: a writer never renames over, nor writes into, a
    device node, a FIFO, a socket or a folder."""
    try:
        mode = os.stat(path).st_mode
    except (FileNotFoundError, NotADirectoryError):
        return  # new (or a dangling link, whose target is created)
    except OSError as exc:
        raise FileFormatError(f"cannot {action} {path}: {exc.strerror}") from None
    if stat.S_ISREG(mode):
        return
    kind = file_kind(mode)
    link = f" (a symbolic link to {os.path.realpath(path)})" if os.path.islink(path) else ""
    if stat.S_ISDIR(mode):
        raise FileFormatError(f"cannot {action} {path}{link}: it is a directory")
    raise FileFormatError(f"cannot {action} {path}{link}: it is {kind}, not a regular file; "
                          "mmsnap writes regular files only (it never replaces or writes "
                          "into a device, FIFO or socket)")


def check_output_path(path: str | os.PathLike) -> Path:
    """``path`` as a :class:`Path` when a file can be written there: its folder
    exists and it is new or a regular file (through symlinks: the file it
    names); else :class:`FileFormatError` naming it and what it is (a folder,
    a device node, a FIFO, a socket). Commands call it before long
    computations."""
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    _refuse_special(path, "write")
    if not folder.is_dir():
        raise FileFormatError(f"cannot write {path}: folder {folder} does not exist")
    return path


def refuse_existing(path: str | os.PathLike, *, overwrite: bool) -> None:
    """The rule of every file written: an existing ``path`` is replaced only
    with ``overwrite`` (the command line's ``--overwrite``); else
    :class:`FileFormatError` naming it."""
    if not overwrite and os.path.lexists(path):
        raise FileFormatError(f"{path} exists; pass --overwrite (overwrite=True) to replace it")


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # exists, owned by someone else
        return True
    return True


def remove_stale_temporaries(path: str | os.PathLike, *,
                             max_age_s: float = STALE_TMP_AGE_S) -> list[Path]:
    """Remove the temporary files and scratch folders (:func:`scratch_folder`)
    a killed writer of ``path`` left beside it (module docstring); returns
    the paths removed. Those of a live writer are kept."""
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    removed = []
    now = time.time()
    for tmp in folder.glob(f".{glob_escape(path.name)}.*.tmp"):
        owner = _TMP_OWNER.search(tmp.name)
        try:
            age = now - tmp.lstat().st_mtime
        except FileNotFoundError:
            continue
        dead = owner is not None and owner.group(2) == _HOST and not _pid_alive(int(owner.group(1)))
        if dead or age > max_age_s:
            with contextlib.suppress(FileNotFoundError, PermissionError):
                if tmp.is_dir() and not tmp.is_symlink():
                    shutil.rmtree(tmp)
                else:
                    tmp.unlink()
                removed.append(tmp)
                _log.info("removed %s, left by an interrupted write", tmp)
    return removed


@contextlib.contextmanager
def scratch_folder(path: str | os.PathLike) -> Iterator[Path]:
    """A scratch folder for the writer of ``path``, beside it (not in
    ``$TMPDIR``), named as its temporary files are: removed when the block
    ends, and, when a ``kill -9`` left it, by the next write of ``path``
    (:func:`remove_stale_temporaries`)."""
    path = Path(os.path.realpath(path))
    folder = path.parent
    remove_stale_temporaries(path)
    scratch = tempfile.mkdtemp(prefix=temporary_prefix(path), suffix=".tmp",
                               dir=folder)
    try:
        yield Path(scratch)
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


def glob_escape(name: str) -> str:
    """``name`` with the glob metacharacters ``*?[`` escaped."""
    return re.sub(r"([*?[])", r"[\1]", name)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success rename it to ``path``.

    The caller writes the whole file to the yielded path (by any means: h5py,
    ``ndarray.tofile``, ``shutil.copyfile``, ...). If the block raises, the
    temporary file is removed and ``path`` is left as it was. A ``path``
    that is not a regular file (a folder, a device node, a FIFO, a socket)
    or lies in a missing folder raises :class:`FileFormatError`, before
    anything is written.
    A ``path`` that is a symlink: the file it points to is replaced (the
    link stays a link).
    """
    check_output_path(path)
    # Through a symlink the file it names is replaced, not the link.
    path = check_output_path(os.path.realpath(path))
    folder = path.parent
    remove_stale_temporaries(path)
    fd, tmp = tempfile.mkstemp(prefix=temporary_prefix(path), suffix=".tmp",
                               dir=folder)
    os.close(fd)
    try:
        yield Path(tmp)
        os.chmod(tmp, 0o666 & ~_umask())
        _check_still_regular(path)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def open_regular(path: str | os.PathLike, *, encoding: str = "utf-8"):
    """``path`` open for writing text as a stream (``mmsnap live -o``: each
    line shows as it is written, for ``tail -f``; not atomic), only when it
    is new or a regular file (through a symlink: the file it names), emptied
    first. A device node, FIFO, socket or folder is refused at the open
    itself (opened without blocking, then checked): never written into, never
    waited on, even when one took the file's place after the command's
    checks. :class:`FileFormatError` naming it and what it is."""
    path = Path(path)
    flags = os.O_WRONLY | os.O_CREAT | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0)
    try:
        fd = os.open(path, flags, 0o666)
    except OSError as exc:
        if exc.errno in (errno.ENXIO, errno.EISDIR, errno.ENODEV):  # a FIFO nobody reads, ...
            _refuse_special(path, "write")
        raise
    mode = os.fstat(fd).st_mode
    if not stat.S_ISREG(mode):
        os.close(fd)
        raise FileFormatError(f"cannot write {path}: it is {file_kind(mode)}, not a regular "
                              "file; mmsnap writes regular files only (it never replaces or "
                              "writes into a device, FIFO or socket)")
    os.set_blocking(fd, True)
    os.ftruncate(fd, 0)
    return os.fdopen(fd, "w", encoding=encoding)


def _check_still_regular(path: Path) -> None:
    """Just before the rename: ``path`` (its real path, resolved at the
    start) is still new or a regular file, not a device, FIFO or link put
    there meanwhile."""
    try:
        mode = os.lstat(path).st_mode
    except FileNotFoundError:
        return
    if not stat.S_ISREG(mode):
        raise FileFormatError(f"cannot write {path}: it became {file_kind(mode)} while it "
                              "was written; left as it is")


def _lock_file(path: Path) -> Path:
    folder = path.parent if str(path.parent) else Path(".")
    return folder / f".{path.name}.lock"


def _open_lock(lock: Path):
    """The lock file open for reading and writing, created new (``O_EXCL``)
    or an existing regular file; never through a symlink (``O_NOFOLLOW``: a
    planted ``.<name>.lock`` link must not create or truncate the file it
    names) nor a FIFO or device (``O_NONBLOCK``, then refused). None when it
    vanished between the two opens."""
    flags = os.O_RDWR | os.O_NONBLOCK | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0)
    try:
        fd = os.open(lock, flags | os.O_CREAT | os.O_EXCL, 0o666)
    except FileExistsError:
        try:
            fd = os.open(lock, flags)
        except FileNotFoundError:
            return None
        except OSError as exc:
            if exc.errno != errno.ELOOP:
                raise
            raise FileFormatError(f"lock file {lock} is a symbolic link (to "
                                  f"{os.path.realpath(lock)}): refusing to follow it; remove "
                                  "it if no mmsnap process is writing the file") from None
    mode = os.fstat(fd).st_mode
    if not stat.S_ISREG(mode):
        os.close(fd)
        raise FileFormatError(f"lock file {lock} is {file_kind(mode)}, not a regular file; "
                              "remove it if no mmsnap process is writing the file")
    return os.fdopen(fd, "r+b", buffering=0)


def _acquire(lock: Path, path: Path, timeout_s: float):
    """The open, flocked lock file. The holder removes the file when done, so
    after locking check that the name still refers to the file locked (else
    another process removed it meanwhile: start again)."""
    deadline = time.monotonic() + timeout_s
    waited = False
    while True:
        fh = _open_lock(lock)
        if fh is None:  # removed between our two opens: start again
            continue
        try:
            fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            fh.close()
            if not waited:
                _log.warning("%s is being written by another process; waiting", path)
                waited = True
            if time.monotonic() > deadline:
                raise FileFormatError(f"{path} is locked by another process writing it "
                                      f"(lock file {lock}); gave up after {timeout_s:g} s"
                                      ) from None
            time.sleep(0.05)
            continue
        try:
            same = os.lstat(lock).st_ino == os.fstat(fh.fileno()).st_ino
        except FileNotFoundError:
            same = False
        if same:
            return fh
        fh.close()


@contextlib.contextmanager
def recording_lock(path: str | os.PathLike, *, timeout_s: float = LOCK_TIMEOUT_S
                   ) -> Iterator[None]:
    """Hold the advisory lock of the file at ``path`` (module docstring):
    wait for another process holding it (up to ``timeout_s``, then
    :class:`FileFormatError` naming the file). Re-entrant in a process.
    Every name of one file (a symlink, a relative path) takes the same lock:
    the lock file lies beside the real path."""
    path = Path(os.path.realpath(path))
    _refuse_special(path, "lock")
    if fcntl is None or not (path.parent if str(path.parent) else Path(".")).is_dir():
        yield  # no locking here (or nowhere to put the lock: the write will say why)
        return
    lock = _lock_file(path)
    key = os.path.realpath(lock)
    with _held_guard:
        entry = _held.get(key)
        if entry is not None:
            entry[1] += 1
    if entry is None:
        try:
            fh = _acquire(lock, path, timeout_s)
        except PermissionError as exc:  # read-only folder: nobody else can write either
            _log.debug("no lock for %s: %s", path, exc)
            yield
            return
        with _held_guard:
            _held[key] = entry = [fh, 1]
    try:
        yield
    finally:
        with _held_guard:
            entry[1] -= 1
            last = entry[1] == 0
            if last:
                del _held[key]
        if last:
            with contextlib.suppress(OSError):
                os.unlink(lock)  # while still locked (see _acquire)
            fcntl.flock(entry[0].fileno(), fcntl.LOCK_UN)
            entry[0].close()
