"""``mmsnap evaluate``: metrics of a recording with truth.

The fused states of its ``/fused`` group (``mmsnap fuse``) and each node's
tracks against the true states (RMSE of position and velocity, NEES of the
fused covariances), and the calibrated node poses against the true ones
(:func:`mmsnap_graph.app.evaluation.evaluate_recording`). Prints a table, or JSON
with ``--json`` for scripts. A failed consistency check (the fused NEES
outside its 95% interval) is printed with its value and interval; with
``--check`` it makes the exit status 1.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys

import numpy as np

from .arguments import HEADING_HELP, named_pose


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "evaluate",
        help="RMSE / pose errors / NEES of a recording's fused states, tracks and poses vs truth",
        description="Compare a recording's one-shot estimates (/fused group), node tracks and "
                    "calibrated node poses with its ground truth (simulated recordings).")
    p.add_argument("recording", help="HDF5 recording with /truth (docs/FORMAT.md)")
    p.add_argument("--calibration", default=None,
                   help="calibration JSON whose poses are evaluated and used to place the "
                        "tracks (default: the poses stored on the nodes)")
    p.add_argument("--surveyed", action="append", type=named_pose, default=[],
                   metavar="NAME=X,Y,PHI_DEG",
                   help="a surveyed node pose, x, y in metres (repeat) to score the "
                        "calibrated poses against, in place of /truth's; a recording without "
                        f"/truth (a real capture) then gets pose errors alone. {HEADING_HELP}")
    p.add_argument("--json", action="store_true",
                   help="print the metrics as JSON (angles in radians, as in the files)")
    p.add_argument("--check", action="store_true",
                   help="exit with status 1 when a consistency check fails (the fused states' "
                        "mean NEES outside its 95%% chi-square interval)")
    p.set_defaults(func=run)


def _f(v, digits=3) -> str:
    return "n/a" if v is None or not np.isfinite(v) else f"{v:.{digits}f}"


def format_metrics(m: dict, path: str) -> str:
    """The metrics of :func:`evaluate_recording` as text tables."""
    lines = [f"{path}: {m['n_targets']} target(s), {m['n_truth_rows']} truth rows", ""]
    lines.append("Node poses vs truth")
    lines.append(f"{'node':6} {'position err [m]':>17} {'heading err [deg]':>18} {'path err [m]':>13}")
    for name, row in m["poses"].items():
        if row is None:
            lines.append(f"{name:6} {'n/a':>17} {'n/a':>18} {'n/a':>13}")
        else:
            lines.append(f"{name:6} {_f(row['position_error_m']):>17} "
                         f"{np.degrees(row['heading_error_rad']):>+18.3f} {_f(row['path_error_m']):>13}")
    lines.append("")
    lines.append("States vs truth")
    lines.append(f"{'estimate':18} {'rows':>6} {'pos. RMSE [m]':>14} {'vel. RMSE [m/s]':>16} "
                 f"{'NEES mean (95% interval)':>28}")
    fu = m["fused"]
    if fu is not None:
        nz = fu["nees"]
        lines.append(f"{'fused (' + fu['mode'] + ')':18} {fu['n_frames']:>6} "
                     f"{_f(fu['position_rmse_m']):>14} {_f(fu['velocity_rmse_mps']):>16} "
                     f"{_f(nz['mean'], 2):>10} ({_f(nz['interval_95'][0], 2)}, "
                     f"{_f(nz['interval_95'][1], 2)})")
        ob = fu["observed_by_all_nodes"]
        lines.append(f"{'  seen by all nodes':18} {ob['n_frames']:>6} {_f(ob['position_rmse_m']):>14} "
                     f"{_f(ob['velocity_rmse_mps']):>16}")
    for name, row in m["tracks"].items():
        if row is not None:
            lines.append(f"{'tracks ' + name:18} {row['n_frames']:>6} {_f(row['position_rmse_m']):>14} "
                         f"{_f(row['velocity_rmse_mps']):>16} {'':>28}")
    if fu is not None and fu["nees"].get("passed") is True:
        lo, hi = fu["nees"]["interval_95"]
        lines.append(f"NEES check passed: mean {fu['nees']['mean']:.2f} inside "
                     f"({lo:.2f}, {hi:.2f})")
    for failure in m.get("failed_checks", []):
        lines.append(f"FAILED: {failure}")
    for n in m["notes"]:
        lines.append(f"note: {n}")
    return "\n".join(lines)


def surveyed_truth(rec, surveyed: dict):
    """``rec``'s truth with its node poses replaced by ``surveyed`` (name ->
    (3,) pose, radians), or a truth of surveyed poses alone (no trajectory)
    when the recording has none. A name that is not a node is a
    :class:`ValidationError`."""
    from mmsnap_graph.data.recording import Truth
    from mmsnap_graph.errors import ValidationError
    unknown = sorted(set(surveyed) - set(rec.nodes))
    if unknown:
        raise ValidationError(f"--surveyed {unknown[0]}: no such node (nodes: {rec.node_names})")
    poses = {name: np.asarray(pose, dtype=float) for name, pose in surveyed.items()}
    if rec.truth is not None:
        return dataclasses.replace(rec.truth, node_poses={**rec.truth.node_poses, **poses})
    return Truth(frame=np.zeros(0, np.int64), target_id=np.zeros(0, np.int64),
                 state=np.zeros((0, 4)), node_poses=poses)


def run(args: argparse.Namespace) -> int:
    import h5py

    from ..evaluation import evaluate_recording
    from mmsnap_graph.io import read_recording
    from mmsnap_graph.io.guard import read_guard
    from mmsnap_graph.io.fused import FUSED_GROUP, read_fused
    from mmsnap_graph.app.runs import calibration_poses_for

    rec = read_recording(args.recording, load_cubes=False)
    if args.surveyed:
        rec = dataclasses.replace(rec, truth=surveyed_truth(rec, dict(args.surveyed)))
    if rec.truth is None:  # the file lacks what evaluate needs: a data error (exit 1)
        from mmsnap_graph.errors import FileFormatError
        raise FileFormatError(f"{args.recording} has no truth (/truth): nothing to evaluate "
                              f"against (give surveyed poses with --surveyed NAME=X,Y,PHI_DEG)")
    with read_guard(args.recording), h5py.File(args.recording, "r") as f:
        has_fused = FUSED_GROUP in f
    fused = read_fused(args.recording) if has_fused else None
    # a node the JSON lacks is an error, as in `mmsnap fuse` (not the recording's pose)
    poses = calibration_poses_for(args.calibration, rec.node_names) if args.calibration else None
    metrics = evaluate_recording(rec, fused=fused, node_poses=poses)
    metrics["recording"] = str(args.recording)
    if args.json:
        json.dump(metrics, sys.stdout, indent=1, default=float)
        sys.stdout.write("\n")
    else:
        print(format_metrics(metrics, str(args.recording)))
    if metrics["failed_checks"]:
        if args.json:  # the table already says it
            for failure in metrics["failed_checks"]:
                print(f"mmsnap evaluate: {failure}", file=sys.stderr)
        if args.check:
            return 1
    return 0
