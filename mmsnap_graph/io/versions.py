"""``format_version`` attributes of the groups a recording file holds.

A version is ``"major.minor"``; a reader reads every minor version of its
major version (a newer minor version only adds fields) and refuses another
major version, whose fields may mean something else.
"""

from __future__ import annotations

from typing import Any, Mapping

from ..errors import FileFormatError

__all__ = ["check_format_version"]


def check_format_version(attrs: Mapping[str, Any], where: str, supported: str) -> str | None:
    """The ``format_version`` of ``attrs`` (None when absent) if its major
    version is ``supported``'s; else :class:`FileFormatError` naming
    ``where`` (the file and group) and both versions."""
    if "format_version" not in attrs:
        return None
    raw = attrs["format_version"]
    version = raw.decode(errors="replace") if isinstance(raw, bytes) else str(raw)
    major = version.split(".")[0].strip()
    if not major.isdigit():
        raise FileFormatError(f"{where} attribute format_version={version!r} must look like "
                              f"{supported!r}")
    if int(major) != int(supported.split(".")[0]):
        raise FileFormatError(f"{where} has format_version {version!r}; this reader reads "
                              f"version {supported.split('.')[0]}.x (a newer mmsnap_graph "
                              "wrote it?)")
    return version
