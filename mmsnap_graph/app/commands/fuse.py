"""``mmsnap fuse``: one-shot fusion of every frame of a recording.

Writes the fused states, covariances and per-frame flags into the recording's
``/fused`` group (layout: :data:`mmsnap_graph.io.fused.FUSED_LAYOUT`), or into
a copy of the recording given by ``--output``.

The measurement noise: ``--sigmas`` when given; else each node's sigmas of
the recording's ``/noise`` group (estimated from the data by ``mmsnap
calibrate`` or ``mmsnap noise``); else the paper's, said so. The fusion flags (shared
with ``mmsnap batch`` and ``mmsnap replay``, and the ``[fuse]`` table of
``--config``) build one :class:`~mmsnap_graph.fusion.config.FusionConfig`
(:func:`~mmsnap_graph.app.commands.arguments.fusion_config`): robust fusion
and every check are on by default (docs/ROBUST.md).
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from mmsnap_graph._atomic import check_output_path, recording_lock
from mmsnap_graph.app.commands.file_rules import add_overwrite
from mmsnap_graph.app.runs import fuse_stored

from .arguments import (add_calibration_arguments, add_fusion_arguments,
                        add_self_check_argument, calibration_for, config_text, fusion_config,
                        say_self_check)


#: Fraction of flagged rows above which ``mmsnap fuse`` exits 1: nearly
#: every row (clean simulated recordings flag well under half of theirs).
#: Rows the room checks flag (``--bounds``, ``--in-front``, the body check)
#: are what the user asked for and do not count.
DEFAULT_MAX_FLAGGED = 0.9


def _fraction(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"must be a fraction in [0, 1], got {text!r}")
    return value


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "fuse",
        help="one-shot fusion of every frame (MAP or ML) into the recording's /fused group",
        description="Fuse every target in every frame of a recording with the calibrated node "
                    "poses (paper eq. 18): MAP with the paper's prior or ML, Laplace or grid "
                    "covariance, then the checks (docs/ROBUST.md). Frames that cannot be fused "
                    "are flagged, not dropped. Reads and writes the recording window by window "
                    "(bounded memory).")
    p.add_argument("recording", help="HDF5 recording (docs/FORMAT.md)")
    add_calibration_arguments(p)
    add_fusion_arguments(p, solvers=("vectorized", "gtsam", "scalar"))
    p.add_argument("-o", "--output", default=None,
                   help="write a copy of the recording with /fused here instead of updating it")
    p.add_argument("--max-flagged", type=_fraction, default=DEFAULT_MAX_FLAGGED,
                   metavar="FRACTION",
                   help="exit 1 when more than this fraction of the fused rows are flagged "
                        "(the rows are written either way; 1 never fails; default "
                        "%(default)s)")
    p.add_argument("--json", action="store_true",
                   help="print a JSON summary to stdout instead of the text (rows, successes, "
                        "the covariance self-check); the words go to stderr")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_self_check_argument(p)
    add_overwrite(p)
    p.set_defaults(func=run)


def rows_text(path) -> str:
    """What the row counts of ``path``'s ``/fused`` mean: a row is one
    (frame, target) pair of the association, so a frame where the nodes'
    detections lie farther apart than its gate holds several targets, each
    seen by fewer nodes; and the flagged rows by status."""
    import h5py

    from mmsnap_graph.data.results import Status
    from mmsnap_graph.io.fused import FUSED_GROUP
    from mmsnap_graph.io.guard import read_guard

    with read_guard(path), h5py.File(path, "r") as f:
        g = f[FUSED_GROUP]
        frame, observed, status = g["frame"][:], g["observed"][:], g["status"][:]
        n_nodes = observed.shape[1] if observed.ndim == 2 else 0
    n_seen = observed.sum(axis=1) if observed.ndim == 2 else np.zeros(frame.size, int)
    _, per_frame = np.unique(frame, return_counts=True)
    lines = [f"  rows: one per (frame, target) of the association; {int(np.sum(n_seen == n_nodes))} "
             f"seen by all {n_nodes} nodes, {int(np.sum(n_seen < n_nodes))} by fewer",
             f"  {int(np.sum(per_frame > 1))} frames hold more than one target: detections "
             f"farther apart than the association gate stay separate targets (a second person, "
             f"clutter, a ghost, or one person placed apart by the nodes)"]
    codes, counts = np.unique(status[status != 0], return_counts=True)
    if codes.size:
        lines.append("  flagged by status: " + ", ".join(
            f"{n} {Status(int(c)).name.lower()} ({int(c)})" for c, n in zip(codes, counts)))
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    import json

    from mmsnap_graph.io.chunks import open_detection_windows

    out = sys.stderr if args.json else sys.stdout
    config = fusion_config(args)
    if args.output is not None:
        check_output_path(args.output)
    # The lock spans read -> write: a concurrent `mmsnap process` or
    # `calibrate` of the same file waits instead of being overwritten.
    with recording_lock(args.recording):
        # Node names only: the detections are read, fused and written window
        # by window (long recordings in bounded memory).
        names = open_detection_windows(args.recording,
                                       source=config.association.source).node_names
        cal = calibration_for(args, args.recording, names, config)
        for line in cal.text:
            print(line, file=out)
        print(config_text(config), file=out)
        fused, _ = fuse_stored(args.recording, config, output=args.output, calibration=cal,
                               progress=False if args.no_progress else None)
    n_ok, path, frames = fused.n_success, fused.path, fused.n_frames
    robust = "none" if config.robust is None else config.robust.kernel
    print(f"fused {fused.n_rows} targets in {frames} frames ({config.mode}, "
          f"{config.solve.covariance}, {config.solve.solver}, robust {robust}): {n_ok} succeeded, "
          f"{fused.n_rows - n_ok} flagged; wrote {path}:/fused", file=out)
    print(rows_text(path), file=out)
    for wall in fused.room.walls:
        print(f"  learned wall of {wall}", file=out)
    if fused.room.outside or fused.room.duplicate:
        beyond = (f" ({fused.room.beyond_wall} beyond a learned wall)"
                  if fused.room.beyond_wall else "")
        print(f"room checks flagged {fused.room.outside} target(s) outside the bounds{beyond} "
              f"and {fused.room.duplicate} duplicate(s) of a body", file=out)
    report = fused.consistency
    if not args.no_self_check:
        say_self_check("fuse", report, out)
    if args.json:
        print(json.dumps({"path": str(path), "n_rows": fused.n_rows, "n_success": n_ok,
                          "n_frames": frames,
                          "consistency": None if report is None else report.to_dict()}))
    room = fused.room.outside + fused.room.duplicate
    return flagged_exit(fused.n_rows - room, n_ok, args.max_flagged)


def flagged_exit(n_rows: int, n_ok: int, max_flagged: float) -> int:
    """Exit 1, saying why, when more than ``max_flagged`` of the rows are
    flagged (a wrong pose, a unit mistake in the calibration or sigmas
    fuses "successfully" into flags); else 0."""
    flagged = n_rows - n_ok
    if n_rows and flagged > max_flagged * n_rows:
        print(f"mmsnap fuse: error: {flagged} of {n_rows} fused rows ({flagged / n_rows:.0%}) are "
              f"flagged, more than --max-flagged {max_flagged:g}: check the node poses (a "
              f"calibration in degrees?) and the sigmas; the rows are written with their "
              f"flags", file=sys.stderr)
        return 1
    return 0
