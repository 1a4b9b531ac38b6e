"""``mmsnap record``: TI boards -> one HDF5 recording, every board on the host's
clock (docs/LIVE.md).

Sends each board its ``.cfg`` (unless ``--no-send-cfg``), reads every data
port in its own thread, stamps each frame with the host's monotonic clock,
puts the boards' frames on one frame grid (so ``mmsnap calibrate`` needs no
lag search for boards started seconds apart) and writes the recording
atomically when ``--duration`` has passed or at Ctrl-C. The per-board
counters (bad packets, missing frame numbers, saturated UART) are printed
and stored in the metadata.
"""

from __future__ import annotations

import argparse
import sys

from ..file_rules import add_overwrite
from .board_args import (add_board_options, board_specs, mountings, pump, report_lines,
                         session_for)


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "record", help="record TI boards on serial ports into one recording (one clock)",
        description="Configure TI mmWave boards over their CLI ports, read their data ports on "
                    "the host's clock and write one HDF5 recording (docs/LIVE.md).")
    p.add_argument("-o", "--output", default=None, help="output HDF5 recording")
    p.add_argument("--list-ports", action="store_true",
                   help="list the serial ports (device, usb:SERIAL, description) and exit")
    add_board_options(p)
    add_overwrite(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if args.list_ports:
        from mmsnap_graph.io.ti.serial.boards import list_boards
        print("\n".join(list_boards()) or "no serial port found")
        return 0
    from mmsnap_graph.errors import ValidationError
    from mmsnap_graph.io import write_recording
    from mmsnap_graph.io.ti.serial.session import FrameCollector
    if args.output is None:
        raise ValidationError("give the output recording: -o FILE.h5")
    specs = board_specs(args)
    session = session_for(args, specs)
    mounts = mountings(args, specs, session.timing)
    collector = FrameCollector([s.name for s in specs], session.frame_period_s, t0_s=session.t0_s)
    with session:
        print(f"recording {len(specs)} board(s) at {1 / session.frame_period_s:g} fps"
              + ("" if args.duration is None else f" for {args.duration:g} s")
              + " (Ctrl-C ends it)", file=sys.stderr)
        why = pump(session, collector.add, args.duration)
    print("\n".join(report_lines(session)), file=sys.stderr)
    md = {f"{name}_{key}": value for name, reader in session.readers.items()
          for key, value in reader.report().items()}
    rec = collector.recording(mounting=mounts, height_band_m=args.height_band, metadata=md)
    path = write_recording(args.output, rec, overwrite=args.overwrite)
    n = sum(len(v) for v in collector.frames.values())
    print(f"stopped after {why}: {n} frames of {len(specs)} board(s); wrote {path}")
    return 0
