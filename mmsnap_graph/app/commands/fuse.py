"""``mmsnap fuse``: one-shot fusion of every frame of a recording.

Writes the fused states, covariances and per-frame flags into the recording's
``/fused`` group (layout: :data:`mmsnap_graph.io.fused.FUSED_LAYOUT`), or into
a copy of the recording given by ``--output``.

The measurement noise: ``--sigmas`` when given; else each node's sigmas of
the recording's ``/noise`` group (estimated from the data by ``mmsnap
calibrate`` or ``mmsnap noise``); else the paper's, said so. Robust fusion
(``--robust``, :data:`DEFAULT_ROBUST`) is on by default, with the motion check
of every row against its neighbouring frames (docs/ROBUST.md;
``--no-motion-check`` turns it off).
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from mmsnap_graph._atomic import check_output_path, recording_lock
from mmsnap_graph.app.commands.file_rules import add_overwrite
from mmsnap_graph.app.runs import DEFAULT_ROBUST, fuse_stored, paper_noise, stored_calibration
from mmsnap_graph.data.body import CENTROID_MERGE_RADIUS_M
from mmsnap_graph.errors import ValidationError

from .arguments import solver_choice


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
                    "covariance. Frames that cannot be fused are flagged, not dropped.")
    p.add_argument("recording", help="HDF5 recording (docs/FORMAT.md)")
    p.add_argument("--calibration", default=None,
                   help="calibration JSON ({'nodes': {'S1': {'pose': [x_m, y_m, phi_rad]}, ...}}); "
                        "default: the poses stored in the recording")
    p.add_argument("--mode", choices=["map", "ml"], default="map",
                   help="MAP with the paper's prior, or maximum likelihood (default %(default)s)")
    p.add_argument("--covariance", choices=["laplace", "grid"], default="laplace",
                   help="Laplace (inverse information) or the paper's grid posterior "
                        "covariance (slow) (default %(default)s)")
    p.add_argument("--sigmas", nargs=3, type=float, default=None,
                   metavar=("RANGE_M", "OMEGA_RAD", "DOPPLER_MPS"),
                   help="measurement noise sigmas of every node (OMEGA_RAD: of omega = pi sin(theta), a "
                        "phase in radians, not an angle; default: each node's "
                        "sigmas in the recording's /noise group, estimated from the data by "
                        "`mmsnap calibrate` or `mmsnap noise`; without it the paper's "
                        "resolutions 0.035 m, pi/4 rad, 0.1807 m/s)")
    p.add_argument("--robust", choices=["gate", "huber", "cauchy", "none"],
                   default=DEFAULT_ROBUST,
                   help="robust one-shot fusion: leave out a node whose residual fails the "
                        "chi-square gate (gate), or down-weight it (huber, cauchy); none = "
                        "plain least squares (default %(default)s)")
    p.add_argument("--no-motion-check", action="store_true",
                   help="with --robust: do not check each fused target against the motion of "
                        "the neighbouring frames (default: a target no neighbouring frame "
                        "confirms is refitted without the nodes that disagree, or flagged; "
                        "docs/ROBUST.md)")
    p.add_argument("--solver", type=solver_choice(("vectorized", "gtsam")), default="vectorized",
                   metavar="{vectorized,gtsam}",
                   help="the vectorized numpy solver over many frames or one GTSAM graph per "
                        "frame (default %(default)s)")
    p.add_argument("--source", choices=["centroids", "point_cloud"], default="centroids",
                   help="detections to fuse (default %(default)s)")
    p.add_argument("--gate", type=float, default=0.999,
                   help="association gate probability for several targets (default %(default)s)")
    p.add_argument("--grid-points", type=int, default=21,
                   help="grid points per axis for --covariance grid (default %(default)s)")
    p.add_argument("-o", "--output", default=None,
                   help="write a copy of the recording with /fused here instead of updating it")
    p.add_argument("--no-pose-covariance", action="store_true",
                   help="treat the calibrated poses as exact (default: the calibration's pose "
                        "covariances are included in the fused covariance, docs/CONVENTIONS.md "
                        "'Calibration-aware fusion'; Laplace covariance only)")
    p.add_argument("--no-time-offsets", action="store_true",
                   help="do not bring the nodes' detections to the reference clock with the "
                        "calibration's clock offsets (default: they are)")
    p.add_argument("--bounds", type=_bounds, default=None, metavar="XMIN,XMAX,YMIN,YMAX",
                   help="the room box in the reference frame (m): fused targets outside it are "
                        "flagged (status 11; e.g. reflections via a wall)")
    p.add_argument("--bounds-cfg", default=None, metavar="FILE.cfg",
                   help="the reference radar's people-tracking .cfg: its boundaryBox is the room "
                        "box, and a target standing still outside its staticBoundaryBox is "
                        "flagged (docs/ROBUST.md)")
    p.add_argument("--in-front", action="store_true",
                   help="the radars hang on the room's walls, facing in: a fused target behind "
                        "any radar is outside the room and flagged (status 11)")
    p.add_argument("--no-learned-walls", action="store_true",
                   help="keep fused targets beyond the walls learned from the radars' multipath "
                        "images (default: flagged, status 11, when no --bounds is given; "
                        "docs/ROBUST.md 'Learned walls')")
    p.add_argument("--no-body-merge", action="store_true",
                   help="fuse each of a node's centroids of a frame closer than the merge "
                        f"radius ({CENTROID_MERGE_RADIUS_M:g} m) on its own (default: merged "
                        "into one, as one body split into clusters)")
    p.add_argument("--no-coverage-check", action="store_true",
                   help="with the motion check: keep a target that a radar whose field of view "
                        "covers it does not see in the frames around (default: flagged, "
                        "status 10: a multipath image; docs/ROBUST.md)")
    p.add_argument("--no-body-check", action="store_true",
                   help="keep fused targets of a frame closer than a body's width (default: "
                        "the one seen by fewer nodes is flagged, status 12)")
    p.add_argument("--max-flagged", type=_fraction, default=DEFAULT_MAX_FLAGGED,
                   metavar="FRACTION",
                   help="exit 1 when more than this fraction of the fused rows are flagged "
                        "(the rows are written either way; 1 never fails; default "
                        "%(default)s)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_overwrite(p)
    p.set_defaults(func=run)


def _bounds(text: str) -> tuple[float, float, float, float]:
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 4:
        raise argparse.ArgumentTypeError(f"--bounds {text!r} must look like XMIN,XMAX,YMIN,YMAX "
                                         "in metres (e.g. -2,1.6,0,3.6)")
    return values


def room_options(args) -> tuple[dict, list[str]]:
    """``fuse_file`` room-frame options from ``--bounds`` / ``--bounds-cfg`` /
    ``--no-body-check``, and what they are in words."""
    from mmsnap_graph.fusion.recording.room import DEFAULT_BODY_M, RoomBounds
    from mmsnap_graph.io.ti.cfg import read_boundary_boxes

    opts: dict = {"body_m": None if args.no_body_check else DEFAULT_BODY_M}
    text = ["no body check" if args.no_body_check else f"one target per {DEFAULT_BODY_M:g} m"]
    box = lambda v: RoomBounds(x_min=v[0], x_max=v[1], y_min=v[2], y_max=v[3])
    if args.bounds is not None and args.bounds_cfg is not None:
        raise ValidationError("give --bounds or --bounds-cfg, not both")
    if args.bounds is not None:
        try:
            opts["bounds"] = box(args.bounds)
        except ValidationError as exc:
            raise ValidationError(f"--bounds: {exc}") from None
    elif args.bounds_cfg is not None:
        boxes = read_boundary_boxes(args.bounds_cfg)
        if "boundaryBox" not in boxes and "staticBoundaryBox" not in boxes:
            raise ValidationError(f"--bounds-cfg {args.bounds_cfg}: no boundaryBox or "
                                  "staticBoundaryBox command")
        if "boundaryBox" in boxes:
            opts["bounds"] = box(boxes["boundaryBox"])
        if "staticBoundaryBox" in boxes:
            opts["static_bounds"] = box(boxes["staticBoundaryBox"])
    if args.in_front:
        opts["in_front"] = True
        text.append("targets in front of every radar")
    opts["walls"] = not args.no_learned_walls and "bounds" not in opts
    if opts["walls"]:
        text.append("walls learned from multipath images")
    if "bounds" in opts:
        text.append(f"room bounds {opts['bounds'].text()}")
    if "static_bounds" in opts:
        text.append(f"static bounds {opts['static_bounds'].text()}")
    return opts, text


def motion_text(args) -> str:
    """``", motion check"`` when the run checks rows against their neighbours."""
    return "" if (args.robust == "none" or args.no_motion_check) else ", motion check"


def calibration_for(args, path, node_names):
    """The stored calibration as the options ask for it (poses, their
    covariances, clock offsets, noise; :func:`mmsnap_graph.app.runs.stored_calibration`)."""
    if args.no_pose_covariance:
        covs = False
    elif args.covariance != "laplace":
        covs = "poses exact (pose covariances need --covariance laplace)"
    else:
        covs = True
    cal = stored_calibration(path, node_names, calibration_json=args.calibration,
                             sigmas=args.sigmas, pose_covariances=covs,
                             time_offsets=not args.no_time_offsets)
    return cal.with_default_noise(*paper_noise())


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
    from mmsnap_graph.io.chunks import open_detection_windows

    if args.grid_points < 5 or args.grid_points % 2 == 0:
        raise ValidationError(f"--grid-points must be odd and >= 5, got {args.grid_points}")
    if args.output is not None:
        check_output_path(args.output)
    # The lock spans read -> write: a concurrent `mmsnap process` or
    # `calibrate` of the same file waits instead of being overwritten.
    with recording_lock(args.recording):
        # Node names only: the detections are read, fused and written window
        # by window (long recordings in bounded memory).
        names = open_detection_windows(args.recording, source=args.source).node_names
        cal = calibration_for(args, args.recording, names)
        room, room_text = room_options(args)
        for line in cal.text:
            print(line, file=sys.stdout)
        print("; ".join(room_text), file=sys.stdout)
        from mmsnap_graph.fusion.options import FusionOptions
        from mmsnap_graph.fusion.recording.regroup import DEFAULT_MERGE_BODY_M

        fusion = FusionOptions(covariance=args.covariance, solver=args.solver,
                               source=args.source, gate_probability=args.gate,
                               grid_points_per_axis=args.grid_points,
                               motion_check=args.robust != "none" and not args.no_motion_check,
                               coverage_check=not args.no_coverage_check,
                               body_merge=False if args.no_body_merge else None,
                               merge_body_m=DEFAULT_MERGE_BODY_M)
        options = dict(mode=args.mode, robust=None if args.robust == "none" else args.robust,
                       options=fusion, **room)
        fused, _ = fuse_stored(args.recording, options, output=args.output, calibration=cal,
                               progress=False if args.no_progress else None)
    n_ok, path, frames = fused.n_success, fused.path, fused.n_frames
    print(f"fused {fused.n_rows} targets in {frames} frames ({args.mode}, {args.covariance}, "
          f"{args.solver}, robust {args.robust}{motion_text(args)}): {n_ok} succeeded, "
          f"{fused.n_rows - n_ok} "
          f"flagged; wrote {path}:/fused", file=sys.stdout)
    print(rows_text(path), file=sys.stdout)
    for wall in fused.room.walls:
        print(f"  learned wall of {wall}", file=sys.stdout)
    if fused.room.outside or fused.room.duplicate:
        beyond = (f" ({fused.room.beyond_wall} beyond a learned wall)"
                  if fused.room.beyond_wall else "")
        print(f"room checks flagged {fused.room.outside} target(s) outside the bounds{beyond} "
              f"and {fused.room.duplicate} duplicate(s) of a body", file=sys.stdout)
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
