"""Checking a ``mmsnap batch --scheduler`` address before Dask connects.

Dask's client trusts what answers on the port: a service that accepts the
connection and never speaks held it past its own timeout (over 90 s asked for
10), and one that speaks another protocol (an HTTP or SSH banner) had its
first 8 bytes read as a message length (a 3 EiB allocation, MemoryError).
A Dask scheduler speaks first: on accepting a connection it sends its
handshake, 8 bytes of little-endian message length (tens of bytes) then the
message. :func:`check_scheduler` connects, reads those 8 bytes within the
time limit and refuses anything that is not a plausible handshake, so the
client is only started on an address that is a Dask scheduler.
"""

from __future__ import annotations

import socket
import struct
import time

from ..errors import ValidationError

__all__ = ["check_scheduler", "MAX_HANDSHAKE_BYTES"]

#: A Dask handshake is a few hundred bytes; a length beyond this is another
#: protocol's bytes read as a length.
MAX_HANDSHAKE_BYTES = 1 << 20


def _host_port(address: str) -> tuple[str, int]:
    scheme, sep, rest = address.partition("://")
    if not sep:
        scheme, rest = "tcp", address
    if scheme != "tcp":
        raise ValidationError(f"--scheduler {address}: only tcp:// scheduler addresses are "
                              f"supported (got {scheme}://; tls and ucx need a security or "
                              f"UCX setup that mmsnap batch does not make)")
    host, sep, port = rest.rstrip("/").rpartition(":")
    host = host.strip("[]")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ValidationError(f"--scheduler {address}: expected tcp://HOST:PORT (port 1-65535)")
    return host, int(port)


def _read_prefix(sock: socket.socket, deadline: float, address: str, timeout_s: float) -> bytes:
    data = b""
    while len(data) < 8:
        left = deadline - time.monotonic()
        if left <= 0:
            raise ValidationError(f"--scheduler {address}: connected, but no Dask scheduler "
                                  f"answered within {timeout_s:g} s")
        sock.settimeout(left)
        try:
            chunk = sock.recv(8 - len(data))
        except TimeoutError:
            continue
        if not chunk:
            raise ValidationError(f"--scheduler {address}: the service closed the connection "
                                  f"without a Dask handshake (not a Dask scheduler)")
        data += chunk
    return data


def check_scheduler(address: str, timeout_s: float) -> str:
    """``address`` when a Dask scheduler answers there within ``timeout_s``
    seconds; else a ValidationError saying what answered (nothing, a closed
    port, another protocol, an unsupported scheme)."""
    host, port = _host_port(str(address))
    deadline = time.monotonic() + timeout_s
    try:
        with socket.create_connection((host, port), timeout=timeout_s) as sock:
            prefix = _read_prefix(sock, deadline, address, timeout_s)
    except (OSError, UnicodeError) as exc:
        if isinstance(exc, TimeoutError):
            raise ValidationError(f"--scheduler {address}: no connection within "
                                  f"{timeout_s:g} s") from None
        text = " ".join(str(exc).split())
        raise ValidationError(f"--scheduler {address}: cannot connect ({text})") from None
    (length,) = struct.unpack("<Q", prefix)
    if not 0 < length <= MAX_HANDSHAKE_BYTES:
        raise ValidationError(f"--scheduler {address}: the service there is not a Dask "
                              f"scheduler (it began with {prefix!r})")
    return address
