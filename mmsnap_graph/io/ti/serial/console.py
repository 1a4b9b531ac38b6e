"""A TI demo's CLI port: send a ``.cfg`` line by line, check every reply
(docs/LIVE.md, "What record sends").

The demo echoes each line, then answers ``Done`` (success), ``Ignored:
Sensor is already stopped`` (success: ``sensorStop`` on a stopped board),
``Error -1`` or ``'...' is not recognized as a CLI command`` (failures), and
prints its prompt ``mmwDemo:/>``. The first command after power-up often
arrives garbled (its echo is not the line sent): such a command is sent once
more. :func:`send_cfg` sends ``sensorStop``, ``flushCfg``, the ``.cfg``'s
commands (comments and blank lines dropped, and its own ``sensorStop`` /
``flushCfg`` / ``sensorStart`` lines) and ``sensorStart``; an error names the
board, the line and the reply.
"""

from __future__ import annotations

import re
import time
from dataclasses import dataclass
from typing import Protocol, Sequence

from ....errors import ConfigurationError, DeviceError

__all__ = ["CfgReply", "cfg_commands", "send_command", "send_cfg", "PROMPT", "REPLY_TIMEOUT_S"]

PROMPT = b"mmwDemo:/>"
#: Seconds to wait for a reply (some commands, e.g. sensorStart, take ~1 s).
REPLY_TIMEOUT_S = 5.0
#: Times a command whose echo came back garbled is sent again.
GARBLED_RETRIES = 1
_FRAME_COMMANDS = ("sensorStop", "flushCfg", "sensorStart")
_FAILURE = re.compile(r"^(Error\b.*|.*is not recognized.*|.*Invalid usage.*)$", re.M)


class Port(Protocol):      # the part of pyserial's Serial used here
    def write(self, data: bytes) -> int | None: ...
    def read(self, size: int = 1) -> bytes: ...


@dataclass(frozen=True, kw_only=True, slots=True)
class CfgReply:
    """What the board answered to one line: ``line`` (its number in the
    ``.cfg``, 0 for the commands added around it), ``command``, ``reply``
    (the text before the prompt), ``tries``."""

    line: int
    command: str
    reply: str
    tries: int = 1


def cfg_commands(text: str) -> list[tuple[int, str]]:
    """``(line number, command)`` to send for a ``.cfg``'s text: its commands
    without comments, between ``sensorStop`` + ``flushCfg`` and ``sensorStart``."""
    body = []
    for number, raw in enumerate(text.splitlines(), start=1):
        line = " ".join(raw.split("%", 1)[0].split())
        if line and line.split()[0] not in _FRAME_COMMANDS:
            body.append((number, line))
    return [(0, "sensorStop"), (0, "flushCfg"), *body, (0, "sensorStart")]


def _read_reply(port: Port, timeout_s: float) -> bytes:
    """The bytes up to and including the prompt (or what came before the timeout)."""
    deadline = time.monotonic() + timeout_s
    out = bytearray()
    while PROMPT not in out:
        if time.monotonic() > deadline:
            break
        # What has arrived (at least one byte, or nothing by the port's
        # timeout): a read of more bytes than the reply holds waits out the
        # whole timeout on every command.
        chunk = port.read(max(1, int(getattr(port, "in_waiting", 0) or 0)))
        out += chunk
    return bytes(out)


def send_command(port: Port, command: str, *, board: str, line: int = 0,
                 timeout_s: float = REPLY_TIMEOUT_S) -> CfgReply:
    """Send one command and check its reply (module docstring); raises
    :class:`~mmsnap_graph.errors.ConfigurationError` for a refused line and
    :class:`~mmsnap_graph.errors.DeviceError` for no reply."""
    where = f"board {board}: " + (f"line {line} " if line else "") + f"{command!r}"
    tries = 0
    while True:
        tries += 1
        port.write(command.encode("ascii") + b"\n")
        raw = _read_reply(port, timeout_s)
        if PROMPT not in raw:
            raise DeviceError(f"{where}: no reply (prompt {PROMPT.decode()!r}) within "
                              f"{timeout_s:g} s; got {raw[-120:]!r}: is the CLI port right "
                              "(115200 baud) and the board running a TI demo?")
        text = raw[:raw.index(PROMPT)].decode("ascii", "replace").replace("\r", "")
        lines = [x.strip() for x in text.split("\n") if x.strip()]
        echoed = bool(lines) and lines[0] == command
        if echoed or tries > GARBLED_RETRIES:
            break                     # else the first command after power-up: garbled
    reply = "\n".join(lines[1:] if echoed else lines)
    if not echoed:
        raise ConfigurationError(f"{where}: the board's echo {text.strip()!r} is not the line "
                                 f"sent, {tries} times")
    if _FAILURE.search(reply) is not None:
        raise ConfigurationError(f"{where}: the board replied {reply!r}")
    if "Done" in lines or any(x.startswith("Ignored:") for x in lines):
        return CfgReply(line=line, command=command, reply=reply, tries=tries)
    raise ConfigurationError(f"{where}: the board replied {reply!r}, not 'Done'")


def send_cfg(port: Port, text: str, *, board: str, timeout_s: float = REPLY_TIMEOUT_S
             ) -> list[CfgReply]:
    """Send a ``.cfg`` (its text) to a board's CLI port: ``sensorStop``,
    ``flushCfg``, its commands, ``sensorStart``; each reply checked."""
    commands: Sequence[tuple[int, str]] = cfg_commands(text)
    return [send_command(port, cmd, board=board, line=n, timeout_s=timeout_s)
            for n, cmd in commands]
