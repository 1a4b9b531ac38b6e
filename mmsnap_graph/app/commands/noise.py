"""``mmsnap noise``: estimate every node's measurement noise from a recording's
data and store it as the ``/noise`` group (:mod:`mmsnap_graph.io.noise`),
without calibrating.

The estimator is :func:`mmsnap_graph.calibration.network.noise_at_poses`, the
one ``mmsnap calibrate`` stores: cross-node residuals at the node poses (those
stored in the recording, or a calibration JSON) combined with each node's own
centroid sequence, the centroids associated across nodes first when several
share a frame (two people); with no poses, the centroid sequences alone
(:func:`mmsnap_graph.calibration.noise.estimate.estimate_noise`). A stored
``/noise`` (``mmsnap calibrate``'s, or an earlier run's) is replaced only with
``--overwrite``. Each component is printed as estimated,
or as not identified with the value used instead and why. At the poses of a
calibration JSON that are not the recording's own calibrated ones, the range
offset (a body's reflection depth) the cross-node residuals identify there is
estimated, taken out of the ranges first, so that it is not counted twice (as
an offset and as range noise), and stored with the noise and the poses: it is
what ``mmsnap fuse --calibration`` adds at those poses (fuse only reads it).
"""

from __future__ import annotations

import argparse

from mmsnap_graph._atomic import check_output_path, recording_lock
from mmsnap_graph.app.commands.file_rules import add_overwrite


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "noise",
        help="estimate each node's measurement sigmas from the data into /noise",
        description="Estimate every node's range, spatial-frequency and Doppler sigmas from "
                    "the recording's centroids (cross-node residuals at the node poses and "
                    "each node's own centroid sequence) and store them as the /noise group, "
                    "which `mmsnap fuse` uses by default. Components the data cannot identify "
                    "are reported as such, with the fallback used (the paper's sigmas).")
    p.add_argument("recording", help="HDF5 recording (docs/FORMAT.md)")
    p.add_argument("--calibration", default=None,
                   help="calibration JSON with the node poses (default: the poses stored in "
                        "the recording; the /calibration group's frame lags when present)")
    p.add_argument("--method", choices=["auto", "network", "temporal"], default="auto",
                   help="cross-node residuals and centroid sequences combined (auto), or one "
                        "of them (default %(default)s)")
    p.add_argument("-o", "--output", default=None,
                   help="write a copy of the recording with /noise here instead of updating it")
    p.add_argument("--no-write", action="store_true", help="print only; do not write /noise")
    add_overwrite(p, "replace the recording's stored /noise (`mmsnap calibrate`'s or an earlier "
                     "run's) or an existing -o file (default: refuse)")
    p.set_defaults(func=run)


def _lags(path) -> dict[str, int] | None:
    """The frame lags of the recording's /calibration group, or None."""
    import h5py

    from mmsnap_graph.io.calibration import CALIBRATION_GROUP, read_calibration
    from mmsnap_graph.io.guard import read_guard

    with read_guard(path), h5py.File(path, "r") as f:
        has = CALIBRATION_GROUP in f
    return dict(read_calibration(path).lag_frames) if has else None


def _refuse_stored_noise(args) -> None:
    """A /noise already in the recording written in place is replaced only
    with --overwrite (it may be calibrate's, which fuse uses)."""
    import h5py

    from mmsnap_graph.errors import ValidationError
    from mmsnap_graph.io.guard import read_guard
    from mmsnap_graph.io.noise import NOISE_GROUP

    if args.no_write or args.output is not None or args.overwrite:
        return
    with read_guard(args.recording), h5py.File(args.recording, "r") as f:
        stored = NOISE_GROUP in f
    if stored:
        raise ValidationError(f"{args.recording} already holds a /{NOISE_GROUP} group (`mmsnap "
                              f"calibrate`'s or an earlier `mmsnap noise`'s, which `mmsnap fuse` "
                              f"uses); pass --overwrite to replace it, -o COPY.h5 to write a "
                              f"copy, or --no-write to print only")


def _estimate(rec, poses, lags, method):
    """The noise at ``poses`` (None: the recording's stored poses) as
    ``mmsnap calibrate`` estimates it; without two posed nodes, the
    centroid sequences alone."""
    from mmsnap_graph.calibration.network import noise_at_poses
    from mmsnap_graph.calibration.noise.estimate import estimate_noise

    if poses is None:
        poses = {n: rec.nodes[n].pose for n in rec.node_names if rec.nodes[n].pose is not None}
    if len(poses) < 2 or method == "temporal":
        return estimate_noise(rec, poses=poses or None, lag_frames=lags, method=method)
    return noise_at_poses(rec, poses, lags, method=method)


def _depth(args, rec, est) -> tuple[float, str]:
    """The range offset `mmsnap fuse --calibration` adds at the JSON's
    poses (said), so that the noise is estimated on the ranges it fuses:
    a depth left in would be counted twice, as an offset and as noise; and
    what it is in words ("" at the recording's own calibrated poses)."""
    from mmsnap_graph.app.runs import range_offset_for_poses
    from mmsnap_graph.io.calibration import read_calibration_json

    cal = read_calibration_json(args.calibration)
    depth, said = range_offset_for_poses(args.recording, cal,
                                         {n: e.noise for n, e in est.nodes.items()},
                                         recording=rec)
    if said:
        print(said)
    return depth, said


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from mmsnap_graph.fusion.recording.timing import offset_ranges
    from mmsnap_graph.io import read_recording
    from mmsnap_graph.app.runs import calibration_poses_for
    from mmsnap_graph.io.calibration import load_calibration_poses
    from mmsnap_graph.io.noise import RangeOffsetAtPoses, write_noise

    from .calibrate import noise_lines

    if args.output is not None and not args.no_write:
        check_output_path(args.output)
    if args.calibration:
        load_calibration_poses(args.calibration)  # a bad file: refused before the lock
    with recording_lock(args.recording):
        _refuse_stored_noise(args)
        rec = read_recording(args.recording, load_cubes=False)
        # a node the JSON lacks is an error, as in `mmsnap fuse`
        poses = calibration_poses_for(args.calibration, rec.node_names) if args.calibration \
            else None
        lags = _lags(args.recording)
        est = _estimate(rec, poses, lags, args.method)
        offset = None
        if poses is not None:   # the range offset `mmsnap fuse` adds at these poses
            depth, said = _depth(args, rec, est)
            if said:
                offset = RangeOffsetAtPoses(offset_m=depth, poses=poses, message=said)
            if np.isfinite(depth):
                est = _estimate(offset_ranges(rec, depth), poses, lags, args.method)
        print("\n".join(noise_lines(est)))  # as `mmsnap calibrate` prints it
        print(est.message)
        if not args.no_write:
            path = write_noise(args.recording, est, output=args.output, range_offset=offset)
            print(f"wrote {path}:/noise")
    return 0 if est.any_identified else 1
