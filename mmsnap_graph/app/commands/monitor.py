"""``mmsnap monitor``: notice a moved radar in a recording and re-calibrate it.

Runs the decalibration monitor (:mod:`mmsnap_graph.calibration.monitor.decalibration`,
docs/CALIBRATION.md "Noticing a moved radar") over the recording's centroids
with what ``mmsnap calibrate`` stored, read as ``mmsnap fuse`` reads it
(:func:`mmsnap_graph.app.runs.stored_calibration`): the node poses (or
``--poses`` from a calibration JSON), their covariances, the clock offsets
and the ``/noise`` sigmas (pooled over the nodes: the monitor takes one
noise). Prints every change point (node, time, frame, statistic) and the
re-calibrated poses. Read-only:
the recording is not changed. Exit status 0 whether or not a change was found,
1 when a re-calibration failed, 2 on an error.
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings

import numpy as np

from mmsnap_graph._atomic import atomic_path, check_output_path
from mmsnap_graph.app.commands.file_rules import add_overwrite
from mmsnap_graph.errors import MmsnapWarning


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "monitor",
        help="detect a radar that moved during a recording and re-calibrate it",
        description="Compare each node's detections with the target fused from the other "
                    "nodes, frame by frame; a persistent pose error (a bumped radar) raises a "
                    "chi-square statistic over 3-20 s windows. Reports the change points and "
                    "the node's new pose with its covariance. Angles are printed in degrees; the JSON "
                    "holds radians, as the files do.")
    p.add_argument("recording", help="HDF5 recording with node poses (run mmsnap calibrate)")
    p.add_argument("--poses", default=None, metavar="CALIBRATION_JSON",
                   help="node poses from this calibration JSON instead of the recording's")
    p.add_argument("--sigmas", type=float, nargs=3,
                   metavar=("RANGE_M", "OMEGA_RAD", "DOPPLER_MPS"),
                   default=None, help="OMEGA_RAD is the sigma of omega = pi sin(theta), a phase in "
                                      "radians, not an angle; centroid noise of every node (default: the recording's "
                                      "/noise group pooled over the nodes, stored by `mmsnap "
                                      "calibrate`; else the centroid_*_std metadata; else the "
                                      "paper's resolutions)")
    p.add_argument("--threshold", type=float, default=None,
                   help="change threshold on the statistic (default: chi-square(3) at 1e-7, "
                        "about 35.4)")
    p.add_argument("--recalibration-s", type=float, default=15.0,
                   help="seconds of data after a change used to re-calibrate (default "
                        "%(default)s)")
    p.add_argument("--json-out", default=None, metavar="PATH",
                   help="also write the result as JSON to this path (angles in radians)")
    p.add_argument("--json", action="store_true",
                   help="print the result as JSON to stdout instead of the text (angles in "
                        "radians)")
    p.add_argument("--no-progress", action="store_true",
                   help="no progress bar (the bar, over frames, is drawn on stderr when it is "
                        "a terminal)")
    add_overwrite(p)
    p.set_defaults(func=run)


def _pose_text(pose, cov) -> str:
    sd = np.sqrt(np.clip(np.diag(cov), 0, None))
    return (f"({pose[0]:.3f} m, {pose[1]:.3f} m, {np.degrees(pose[2]):.2f} deg) "
            f"+- ({sd[0]:.3f} m, {sd[1]:.3f} m, {np.degrees(sd[2]):.2f} deg)")


def format_result(result) -> str:
    """Change points and re-calibrations as text (angles in degrees)."""
    lines = [f"nodes {', '.join(result.node_names)}; {result.frame.size} frames; threshold "
             f"{result.threshold:.1f}; noise range {result.noise.range_m:.3g} m, omega "
             f"{result.noise.omega_rad:.3g} rad"]
    if not result.changes:
        lines.append("no change detected")
    for c in result.changes:
        lines.append(f"change: {c.node} moved at t={c.time_s:.2f} s (frame {c.frame}); detected "
                     f"t={c.detection_time_s:.2f} s (frame {c.detection_frame}), statistic "
                     f"{c.statistic:.1f} over {c.window_frames} frames")
    for r in result.recalibrations:
        if not r.fit.success:
            lines.append(f"  {r.node} re-calibration FAILED: {r.fit.message}")
            continue
        x, y, phi = r.old_pose
        lines.append(f"  {r.node} new pose from frames {r.first_frame}-{r.last_frame}: "
                     f"{_pose_text(r.fit.pose, r.fit.covariance)}; was ({x:.3f} m, {y:.3f} m, "
                     f"{np.degrees(phi):.2f} deg)")
    return "\n".join(lines)


def result_json(result) -> dict:
    """The result as a JSON-ready mapping (angles in radians)."""
    return {
        "node_order": list(result.node_names),
        "n_frames": int(result.frame.size),
        "threshold": result.threshold,
        "changes": [{"node": c.node, "frame": c.frame, "time_s": c.time_s,
                     "detection_frame": c.detection_frame,
                     "detection_time_s": c.detection_time_s, "statistic": c.statistic,
                     "window_frames": c.window_frames} for c in result.changes],
        "recalibrations": [{"node": r.node, "success": r.fit.success, "message": r.fit.message,
                            "first_frame": r.first_frame, "last_frame": r.last_frame,
                            "old_pose": r.old_pose.tolist(), "pose": r.fit.pose.tolist(),
                            "covariance": r.fit.covariance.tolist()}
                           for r in result.recalibrations],
        "poses": {n: p.tolist() for n, p in result.poses.items()},
    }


def run(args: argparse.Namespace) -> int:
    from mmsnap_graph.app.runs import nominal_texts, stored_calibration
    from mmsnap_graph.calibration.monitor.decalibration import DEFAULT_THRESHOLD, monitor_recording
    from mmsnap_graph.fusion.recording.timing import align_recording
    from mmsnap_graph.io import read_recording

    json_path = check_output_path(args.json_out) if args.json_out else None
    rec = read_recording(args.recording, load_cubes=False)
    cal = stored_calibration(args.recording, rec.node_names, calibration_json=args.poses,
                             sigmas=args.sigmas, per_node_noise=False)
    if cal.noise is None:
        text = ("no /noise group (run `mmsnap calibrate` or `mmsnap noise`): the recording's "
                "centroid noise metadata, else the paper's sigmas")
        cal = cal.with_default_noise(None, text)
    say = (lambda text: print(text, file=sys.stderr)) if args.json else print
    say("\n".join(cal.text))
    if cal.time_offset_s:  # the centroids on the reference clock, as `mmsnap fuse` fuses them
        rec = align_recording(rec, cal.time_offset_s)
    threshold = DEFAULT_THRESHOLD if args.threshold is None else args.threshold
    result = monitor_recording(rec, node_poses=cal.node_poses,
                               node_covariances=cal.pose_covariances,
                               noise=cal.noise, threshold=threshold,
                               recalibration_s=args.recalibration_s,
                               progress=not args.no_progress and sys.stderr.isatty())
    # With --json, stdout holds the JSON alone; the words go to stderr.
    print(json.dumps(result_json(result), indent=2) if args.json else format_result(result))
    for text in nominal_texts(rec.metadata, result.poses, reference=rec.node_names[0]):
        warnings.warn(text, MmsnapWarning, stacklevel=2)
    if json_path is not None:
        with atomic_path(json_path) as tmp:
            tmp.write_text(json.dumps(result_json(result), indent=2) + "\n", encoding="utf-8")
        say(f"wrote {json_path}")
    return 1 if any(not r.fit.success for r in result.recalibrations) else 0
