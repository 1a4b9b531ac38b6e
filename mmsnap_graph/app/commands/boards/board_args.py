"""The options of ``mmsnap record`` and ``mmsnap live``: which boards, their
``.cfg``, mounting, and the session both verbs run."""

from __future__ import annotations

import argparse
import sys

from mmsnap_graph.errors import ValidationError

from ..arguments import named_values

__all__ = ["add_board_options", "board_specs", "session_for", "mountings"]


def _board(text: str):
    from mmsnap_graph.io.ti.serial.boards import parse_board
    try:
        return parse_board(text)
    except ValidationError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_board_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("boards")
    g.add_argument("--board", action="append", type=_board, default=[],
                   metavar="NAME=CLI_PORT,DATA_PORT[,CFG]",
                   help="a board: its node name, CLI port (empty for a board that only "
                        "streams), data port, and the .cfg to send; a port is a device "
                        "(/dev/ttyACM0, COM3) or usb:SERIAL[:INDEX]; NAME=usb:SERIAL[,CFG] "
                        "takes both ports of one USB device; repeat per board")
    g.add_argument("--boards", default=None, metavar="FILE.toml",
                   help="the boards as [boards.NAME] tables (cli, data, cfg, mount)")
    g.add_argument("--cfg", default=None,
                   help="the .cfg for every board that names none")
    g.add_argument("--no-send-cfg", action="store_true",
                   help="send nothing to the CLI ports: the boards already run (their .cfg, "
                        "if given, is only read for the frame period)")
    g.add_argument("--frame-period", type=float, default=None, metavar="SECONDS",
                   help="frame period in seconds (default: from the .cfg)")
    g.add_argument("--demo", choices=["auto", "oob", "tracking", "counting"], default="auto",
                   help="the demo the boards run (default: detected from the bytes)")
    g.add_argument("--mount", action="append", type=named_values("HEIGHT_M,TILT_DEG", 2),
                   default=[], metavar="NAME=HEIGHT_M,TILT_DEG",
                   help="mounting height above the floor and down tilt of a board (repeat; "
                        "default: the TOML file's mount, else the .cfg's sensorPosition, "
                        "else 0, 0)")
    g.add_argument("--height-band", type=_band, default=None, metavar="LOW_M,HIGH_M",
                   help="keep points between these heights above the floor")
    g.add_argument("--duration", type=float, default=None, metavar="SECONDS",
                   help="stop after this many seconds (default: at Ctrl-C)")


def _band(text: str):
    from ..files.import_ import height_band
    return height_band(text)


def board_specs(args: argparse.Namespace) -> list:
    """The boards of ``--board`` and ``--boards``, each with its ``.cfg``."""
    import dataclasses

    from mmsnap_graph.io.ti.serial.boards import read_boards_toml
    specs = list(args.board)
    if args.boards is not None:
        specs += read_boards_toml(args.boards)
    if not specs:
        raise ValidationError("no board: give --board NAME=CLI_PORT,DATA_PORT[,CFG] (repeat) or "
                              "--boards FILE.toml (mmsnap record --list-ports shows the ports)")
    if args.cfg is not None:
        specs = [s if s.cfg else dataclasses.replace(s, cfg=args.cfg) for s in specs]
    if args.duration is not None and not args.duration > 0:
        raise ValidationError(f"--duration must be > 0 seconds, got {args.duration!r}")
    return specs


def mountings(args: argparse.Namespace, specs, timing) -> dict:
    """Each board's :class:`~mmsnap_graph.io.ti.point_cloud.Mounting`: ``--mount``,
    else the TOML file's, else the ``.cfg``'s ``sensorPosition``, else (0, 0)."""
    import numpy as np

    from mmsnap_graph.io.ti.point_cloud import Mounting
    given = dict(args.mount)
    names = [s.name for s in specs]
    unknown = sorted(set(given) - set(names))
    if unknown:
        raise ValidationError(f"--mount names boards {unknown} that are not given (boards: "
                              f"{names})")
    out = {}
    for s in specs:
        height, tilt = given.get(s.name) or s.mount or timing[s.name].mount or (0.0, 0.0)
        try:
            out[s.name] = Mounting(height_m=height, tilt_rad=np.deg2rad(tilt))
        except ValidationError as exc:
            raise ValidationError(f"--mount {s.name}={height:g},{tilt:g}: {exc}") from None
    return out


def session_for(args: argparse.Namespace, specs):
    """The :class:`~mmsnap_graph.io.ti.serial.session.BoardSession` of the options."""
    from mmsnap_graph.io.ti.serial.session import BoardSession
    return BoardSession(specs, frame_period_s=args.frame_period, send_cfg=not args.no_send_cfg,
                        demo=args.demo, log=lambda text: print(text, file=sys.stderr))


def pump(session, on_frame, duration_s: float | None, on_idle=None) -> str:
    """Hand each frame of a running session to ``on_frame`` until
    ``duration_s`` has passed, Ctrl-C (SIGINT) or a reader fails; the frames
    still queued are handed on too. ``on_idle()`` is called when no frame came
    for a tenth of a second. Returns why it stopped."""
    import queue
    import signal
    import threading
    import time

    from mmsnap_graph.errors import DeviceError
    stop = threading.Event()
    previous = None
    if threading.current_thread() is threading.main_thread():
        previous = signal.signal(signal.SIGINT, lambda *_: stop.set())
    end = None if duration_s is None else time.monotonic() + duration_s
    why = "Ctrl-C"
    try:
        while not stop.is_set():
            if end is not None and time.monotonic() >= end:
                why = f"{duration_s:g} s"
                break
            failed = session.errors()
            if failed:
                name, exc = next(iter(failed.items()))
                raise DeviceError(f"board {name}: reading its data port failed: {exc}")
            try:
                frame = session.frames.get(timeout=0.1)
            except queue.Empty:
                if on_idle is not None:
                    on_idle()
                continue
            # Held with the one just taken (a reader may put one more meanwhile).
            held = min(session.frames.qsize() + 1, session.frames.maxsize)
            session.max_queued = max(session.max_queued, held)
            on_frame(frame)
    finally:
        if previous is not None:
            signal.signal(signal.SIGINT, previous)
    session.stop()
    while True:
        try:
            on_frame(session.frames.get_nowait())
        except queue.Empty:
            break
    return why


def report_lines(session) -> list[str]:
    """One line per board: what its reader counted."""
    lines = []
    for name, reader in session.readers.items():
        r = reader.report()
        lines.append(f"{name}: {r['frames']} frames ({r['packets']} packets, {r['bad_packets']} "
                     f"bad, {r['dropped_packets']} out of sequence, {r['missing_frames']} frame "
                     f"numbers missing, {r['saturated']} with the UART saturated, "
                     f"{r['bytes_skipped']} bytes skipped)")
        for problem in list(reader.problems)[:5]:
            lines.append(f"{name}: skipped {problem}")
    return lines
