"""The input files of the importers: a regular file, or an error saying what
the path is instead (reading a pipe or a device would wait for ever)."""

from __future__ import annotations

from pathlib import Path

from ...errors import FileFormatError

__all__ = ["require_file"]


def require_file(path: Path, kind: str) -> Path:
    """``path`` if it is a regular file (or a link to one); else
    :class:`FileFormatError` naming ``kind`` (``"UART log"``) and whether the
    path is missing, a folder or something else (a pipe, a device)."""
    p = Path(path)
    if p.is_file():
        return p
    if not p.exists():
        raise FileFormatError(f"{kind} {p} does not exist")
    what = "a folder" if p.is_dir() else "not a regular file (a pipe or a device?)"
    raise FileFormatError(f"{kind} {p} is {what}")
