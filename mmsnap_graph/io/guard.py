"""Turning what h5py and numpy raise on a damaged file into the project's
:class:`~mmsnap_graph.errors.FileFormatError` naming the file (bit
flips give ``RuntimeError``, ``ValueError``, ``KeyError``, ... besides
``OSError``). Used by every reader of :mod:`mmsnap_graph.io`."""

from __future__ import annotations

import contextlib
import os
import shutil
import stat
from pathlib import Path
from typing import Iterator

import h5py

from .._atomic import atomic_path, recording_lock
from ..errors import FileFormatError, MmsnapError

__all__ = ["H5_ERRORS", "read_guard", "existing_file", "open_for_reading", "open_group",
           "edited_copy", "replace_group"]

#: What h5py and numpy raise on a damaged file.
H5_ERRORS = (OSError, RuntimeError, ValueError, KeyError, TypeError, IndexError, OverflowError,
             UnicodeDecodeError, AttributeError, SystemError)


@contextlib.contextmanager
def read_guard(path: str | os.PathLike) -> Iterator[None]:
    """Any error of h5py or numpy while reading ``path`` (:data:`H5_ERRORS`)
    becomes a :class:`FileFormatError` whose message names the file (and the
    field, where the reader knew it)."""
    name = str(path)
    try:
        yield
    except FileFormatError as exc:
        if str(exc).startswith(name):
            raise
        raise FileFormatError(f"{name}: {exc}") from exc
    except MmsnapError:
        raise
    except H5_ERRORS as exc:
        raise FileFormatError(f"{name} is damaged: {type(exc).__name__}: {exc}") from exc


def existing_file(path: str | os.PathLike) -> Path:
    """``path`` as a :class:`Path` when it names an existing regular file;
    a missing path, or a FIFO, device or socket (opening one would block or
    read for ever), raises :class:`FileFormatError` naming it."""
    path = Path(path)
    try:
        mode = path.stat().st_mode
    except FileNotFoundError:
        raise FileFormatError(f"{path} does not exist") from None
    except OSError as exc:
        raise FileFormatError(f"{path} cannot be read: {exc.strerror or exc}") from None
    if not stat.S_ISREG(mode):
        kind = "a directory" if stat.S_ISDIR(mode) else "not a regular file (a FIFO, device or socket)"
        raise FileFormatError(f"{path} is {kind}; give a recording file")
    return path


@contextlib.contextmanager
def open_for_reading(path: str | os.PathLike) -> Iterator[h5py.File]:
    """The HDF5 file at ``path`` open for reading, inside :func:`read_guard`.
    A missing file, or one h5py cannot open (truncated, corrupt), raises
    :class:`FileFormatError` naming it."""
    path = existing_file(path)
    with read_guard(path):
        try:
            f = h5py.File(path, "r")
        except H5_ERRORS as exc:
            raise FileFormatError(f"{path} is not a readable HDF5 file (truncated or "
                                  f"corrupt?): {exc}") from exc
        with f:
            yield f


@contextlib.contextmanager
def open_group(path: str | os.PathLike, name: str, missing: str) -> Iterator[h5py.Group]:
    """The group ``/name`` of the HDF5 file at ``path``, open for reading,
    inside :func:`read_guard`. A missing file or group, or a file h5py cannot
    open, raises :class:`FileFormatError` naming the file (``missing`` is the
    message's tail for a missing group, e.g. "has no /fused group; ...")."""
    path = Path(path)
    with open_for_reading(path) as f:
        if name not in f:
            raise FileFormatError(f"{path}{missing}")
        yield f[name]


@contextlib.contextmanager
def edited_copy(path: str | os.PathLike, output: str | os.PathLike | None = None
                ) -> Iterator[h5py.File]:
    """The recording at ``path`` copied to a temporary file beside the
    destination (``output``, default ``path``) and open for writing; when the
    block ends without an error the copy is moved over the destination
    (:func:`mmsnap_graph._atomic.atomic_path`), else the destination is left
    as it was. Both files' locks are held throughout (concurrent writers
    wait). A missing or unwritable file raises :class:`FileFormatError`."""
    src = Path(path)
    dst = src if output is None else Path(output)
    with recording_lock(src), recording_lock(dst), atomic_path(dst) as tmp:
        existing_file(src)
        shutil.copyfile(src, tmp)
        try:
            f = h5py.File(tmp, "r+")
        except H5_ERRORS as exc:
            raise FileFormatError(f"{src} is not a writable HDF5 file: {exc}") from exc
        with f:
            yield f


def replace_group(f: h5py.File, name: str, path: str | os.PathLike) -> h5py.Group:
    """A new, empty group ``/name`` of ``f``, replacing an existing one (a
    damaged one that cannot be removed raises :class:`FileFormatError`
    naming ``path``)."""
    try:
        if name in f:
            del f[name]
    except H5_ERRORS as exc:
        raise FileFormatError(f"{path}: /{name} cannot be replaced (damaged file?): "
                              f"{exc}") from exc
    return f.create_group(name)
