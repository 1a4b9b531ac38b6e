"""``mmsnap export``: a recording's fused states or calibrated poses as CSV or
JSON lines, for spreadsheets and other tools
(:mod:`mmsnap_graph.app.export`). Read-only on the recording; the table goes
to standard output, or atomically to ``-o FILE``.
"""

from __future__ import annotations

import argparse
import sys

from mmsnap_graph._atomic import atomic_path


def register(subparsers) -> None:
    from mmsnap_graph.app.export import FORMATS, TABLES

    p = subparsers.add_parser(
        "export",
        help="the /fused rows or the /calibration poses as CSV or JSON lines",
        description="Write a recording's fused states (/fused, from `mmsnap fuse`) or node "
                    "poses (/calibration, from `mmsnap calibrate`) as a table. Columns carry "
                    "their units (x_m, vx_mps, phi_rad, phi_deg, ...); angles are radians with "
                    "a phi_deg twin; track_id is a fused row's person id (the central "
                    "tracker's track; -1 for a row not fused); JSON lines add each row's full covariance. A CSV text cell "
                    "starting with =, +, -, @, tab or CR is written behind a ' so that "
                    "spreadsheets do not run it as a formula.")
    p.add_argument("recording", help="HDF5 recording (docs/FORMAT.md)")
    p.add_argument("table", choices=TABLES, help="what to export")
    p.add_argument("--format", choices=FORMATS, default=None,
                   help="csv or jsonl (default: from the -o suffix, else csv)")
    p.add_argument("-o", "--output", default=None,
                   help="write the table here (default: standard output)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing --output file")
    p.set_defaults(func=run)


def _format(args: argparse.Namespace) -> str:
    if args.format is not None:
        return args.format
    if args.output is not None and str(args.output).lower().endswith((".jsonl", ".ndjson")):
        return "jsonl"
    return "csv"


def run(args: argparse.Namespace) -> int:
    from mmsnap_graph.app.export import (CALIBRATION_COLUMNS, FUSED_COLUMNS, calibration_rows,
                                         fused_rows, write_table)
    from mmsnap_graph.errors import FileFormatError
    from mmsnap_graph.io.guard import open_for_reading

    group = {"fused": ("fuse", fused_rows, FUSED_COLUMNS),
             "calibration": ("calibrate", calibration_rows, CALIBRATION_COLUMNS)}
    verb, rows, columns = group[args.table]
    with open_for_reading(args.recording) as f:
        present = args.table in f
    if not present:
        raise FileFormatError(f"{args.recording} has no /{args.table} group; run "
                              f"`mmsnap {verb} {args.recording}` first")
    text = write_table(rows(args.recording), columns, _format(args))
    if args.output is None:
        sys.stdout.write(text)
        return 0
    with atomic_path(args.output) as tmp:
        tmp.write_text(text, encoding="utf-8")
    print(f"wrote {args.output}", file=sys.stderr)
    return 0
