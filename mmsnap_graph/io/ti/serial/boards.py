"""Which boards, on which ports (docs/LIVE.md, "Finding the ports").

A board is a :class:`BoardSpec`: a node name, its CLI port (None for a board
that only streams), its data port, and the ``.cfg`` it runs. On the command
line a board is ``NAME=CLI_PORT,DATA_PORT[,CFG]`` (:func:`parse_board`); a
TOML file lists the same as ``[boards.NAME]`` tables (:func:`read_boards_toml`)::

    [boards.S1]
    cli = "/dev/ttyACM0"        # or "usb:SERIAL" / "usb:SERIAL:0" (below)
    data = "/dev/ttyACM1"
    cfg = "people.cfg"          # relative to the TOML file
    mount = [1.2, 10.0]         # height in m, down tilt in degrees (optional)

A port is a device path (``/dev/ttyACM0``, ``COM3``, ``/dev/cu.usbmodem...``) or
``usb:SERIAL[:INDEX]``: the ports of the USB device whose serial number is
``SERIAL`` (TI's XDS110 and CP2105 bridges expose two, the CLI port first),
sorted by device name, ``INDEX`` 0 (the default for the CLI port) or 1 (the
default for the data port) (:func:`resolve_port`, from pyserial's
``list_ports``).
"""

from __future__ import annotations

import os
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Sequence

from ....errors import ConfigurationError, DeviceError, ValidationError

__all__ = ["BoardSpec", "parse_board", "read_boards_toml", "resolve_port", "list_boards",
           "CLI_BAUD", "DATA_BAUD"]

#: TI's demos: the CLI port at 115200 8N1, the data port at 921600 8N1.
CLI_BAUD = 115200
DATA_BAUD = 921600
_USB = "usb:"


@dataclass(frozen=True, kw_only=True, slots=True)
class BoardSpec:
    """One board: ``name`` (the node), ``cli_port`` (None: the board only
    streams), ``data_port``, ``cfg`` (the ``.cfg`` file to send or that the
    board runs, or None), ``mount`` ((height_m, tilt_deg) or None)."""

    name: str
    data_port: str
    cli_port: str | None = None
    cfg: str | None = None
    mount: tuple | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name or "/" in self.name \
                or "=" in self.name or "," in self.name:
            raise ValidationError(f"board name {self.name!r} must be a non-empty name without "
                                  "'/', '=' or ','")
        if not self.data_port:
            raise ValidationError(f"board {self.name}: no data port")
        if self.mount is not None:
            if len(self.mount) != 2:
                raise ValidationError(f"board {self.name}: mount={self.mount!r} must be "
                                      "(height_m, tilt_deg)")
            object.__setattr__(self, "mount", tuple(float(v) for v in self.mount))


def parse_board(text: str) -> BoardSpec:
    """``NAME=CLI_PORT,DATA_PORT[,CFG]`` (CLI_PORT may be empty: a board that
    only streams) -> :class:`BoardSpec`; ``NAME=usb:SERIAL[,CFG]`` gives both
    ports of one USB device."""
    name, sep, rest = str(text).partition("=")
    if not sep or not name:
        raise ValidationError(f"--board {text!r} must look like NAME=CLI_PORT,DATA_PORT[,CFG] "
                              "(e.g. S1=/dev/ttyACM0,/dev/ttyACM1,people.cfg)")
    parts = [p.strip() for p in rest.split(",")]
    if parts and parts[0].startswith(_USB) and (len(parts) == 1 or not parts[1].startswith(
            _USB) and not _looks_like_port(parts[1])):
        serial = parts[0]
        return BoardSpec(name=name, cli_port=serial + ":0", data_port=serial + ":1",
                         cfg=parts[1] if len(parts) > 1 and parts[1] else None)
    if len(parts) not in (2, 3):
        raise ValidationError(f"--board {text!r}: give NAME=CLI_PORT,DATA_PORT[,CFG] "
                              f"({len(parts)} comma-separated fields given)")
    cfg = parts[2] if len(parts) == 3 and parts[2] else None
    return BoardSpec(name=name, cli_port=parts[0] or None, data_port=parts[1], cfg=cfg)


def _looks_like_port(text: str) -> bool:
    return text.startswith(("/dev/", "COM", "com", "\\\\.\\"))


def read_boards_toml(path: str | os.PathLike) -> list[BoardSpec]:
    """The ``[boards.NAME]`` tables of a TOML file, in file order (module
    docstring); a ``cfg`` path is relative to the file's folder."""
    p = Path(path)
    try:
        data = tomllib.loads(p.read_text(encoding="utf-8-sig"))
    except OSError as exc:
        raise ConfigurationError(f"cannot read {p}: {exc.strerror or exc}") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ConfigurationError(f"{p} is not a valid TOML file: {exc}") from None
    boards = data.get("boards")
    unknown = sorted(set(data) - {"boards"})
    if unknown or not isinstance(boards, dict) or not boards:
        raise ConfigurationError(f"{p}: expected [boards.NAME] tables only"
                                 + (f" (unknown: {unknown})" if unknown else ""))
    out = []
    for name, table in boards.items():
        if not isinstance(table, dict):
            raise ConfigurationError(f"{p}: boards.{name} must be a table")
        extra = sorted(set(table) - {"cli", "data", "cfg", "mount"})
        if extra or "data" not in table:
            raise ConfigurationError(f"{p}: boards.{name} needs 'data' (and may have 'cli', "
                                     f"'cfg', 'mount'); unknown keys {extra}")
        cfg = table.get("cfg")
        if cfg is not None:
            cfg = str(p.parent / cfg) if not Path(cfg).is_absolute() else str(cfg)
        try:
            out.append(BoardSpec(name=str(name), cli_port=table.get("cli"),
                                 data_port=str(table["data"]), cfg=cfg, mount=table.get("mount")))
        except (TypeError, ValueError) as exc:
            raise ConfigurationError(f"{p}: boards.{name}: {exc}") from None
    return out


def resolve_port(port: str, ports: Sequence | None = None, *, default_index: int = 0) -> str:
    """A device path for ``port``: itself, or for ``usb:SERIAL[:INDEX]`` the
    ``INDEX``-th port (sorted by device) of the USB device with that serial
    number. ``ports`` : pyserial ``ListPortInfo`` records (default: the
    machine's, ``serial.tools.list_ports.comports()``)."""
    if not port.startswith(_USB):
        return port
    serial, _, index = port[len(_USB):].partition(":")
    try:
        k = int(index) if index else default_index
    except ValueError:
        raise ValidationError(f"port {port!r}: INDEX must be an integer (usb:SERIAL:INDEX)") \
            from None
    if ports is None:
        from serial.tools import list_ports
        ports = list_ports.comports()
    mine = sorted((p for p in ports if (p.serial_number or "") == serial), key=lambda p: p.device)
    if not mine:
        seen = sorted({p.serial_number for p in ports if p.serial_number})
        raise DeviceError(f"port {port!r}: no USB serial device has serial number {serial!r} "
                          f"(connected: {seen or 'none'}; mmsnap record --list-ports shows them)")
    if not 0 <= k < len(mine):
        raise DeviceError(f"port {port!r}: the device {serial!r} has {len(mine)} port(s) "
                          f"({', '.join(p.device for p in mine)}), no index {k}")
    return mine[k].device


def list_boards(ports: Iterable | None = None) -> list[str]:
    """One line per serial port: device, USB serial number, description (for
    ``mmsnap record --list-ports``), TI's boards first."""
    if ports is None:
        from serial.tools import list_ports
        ports = list_ports.comports()
    lines = []
    for p in sorted(ports, key=lambda p: (p.vid != 0x0451 and p.vid != 0x10C4, p.device)):
        serial = f"usb:{p.serial_number}" if p.serial_number else "-"
        lines.append(f"{p.device}\t{serial}\t{p.description or ''}")
    return lines
