"""Files built once per test run and shared by the pytest-xdist workers.

The README's test command runs the suite on two workers (``-n 2``); a
session-scoped fixture then runs once per worker. :func:`built_once` builds a
folder of files once for the whole run instead: the first worker to ask builds
it under a lock in the run's shared temporary folder, the others wait and read
it (without xdist, once per session). What it builds is shared: a test reads
the files, or copies them before changing them.
"""

from __future__ import annotations

import fcntl
import os
import shutil
from pathlib import Path
from typing import Callable

__all__ = ["built_once"]


def built_once(tmp_path_factory, name: str, build: Callable[[Path], None]) -> Path:
    """The folder ``name`` after ``build(folder)`` filled it, once per run."""
    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent  # the run's folder; each worker has its own below it
    folder = root / f"once-{name}"
    with open(root / f"once-{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            if not (folder / ".built").is_file():
                shutil.rmtree(folder, ignore_errors=True)  # a build that failed
                folder.mkdir()
                build(folder)
                (folder / ".built").touch()
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)
    return folder
