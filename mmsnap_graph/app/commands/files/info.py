"""``mmsnap info``: what a recording holds, without h5py.

Nodes and their poses, the levels each holds (rows, frames), the frame period
and time span, the metadata, and what ``calibrate``, ``noise`` and ``fuse``
stored (poses with their sigmas and clock offsets, the noise sigmas, the fused
rows with their status counts): :func:`mmsnap_graph.app.recording_info.recording_info`.
Read-only: the file is never changed.
"""

from __future__ import annotations

import argparse
import json


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "info",
        help="what a recording holds: nodes, levels, frames, calibration, noise, fused rows",
        description="Print what an HDF5 recording holds (read-only). Angles are printed in "
                    "degrees; --json prints radians, as stored in the file.")
    p.add_argument("recording", help="HDF5 recording (docs/FORMAT.md)")
    p.add_argument("--json", action="store_true",
                   help="print the summary as JSON (angles in radians, as in the file)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from mmsnap_graph.app.recording_info import format_info, json_ready, recording_info

    info = recording_info(args.recording)  # a file that is not a recording: exit 1
    print(json.dumps(json_ready(info), indent=2, allow_nan=False) if args.json
          else format_info(info))
    return 0
