"""``mmsnap replay``: stream a recording frame by frame through the online API
(:class:`mmsnap_graph.fusion.stream.frame_stream.FrameStream`, docs/STREAMING.md).

Fuses with what ``mmsnap calibrate`` stored, read as ``mmsnap fuse`` reads it
(:func:`mmsnap_graph.app.runs.stored_calibration`: poses or ``--calibration``,
their covariances, the clock offsets, the ``/noise`` sigmas), said on stderr.
Prints one line per frame (or only the summary with ``--summary``); with
``--realtime`` the frames are paced at the recorded frame rate (``--speed``
times faster). Writes nothing unless ``--output`` is given (one JSON object
per frame).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np

from mmsnap_graph.app.commands.file_rules import add_overwrite
from mmsnap_graph.errors import ValidationError

from .arguments import solver_choice


#: Playback speeds --speed accepts (1000 times slower to 10^6 times faster).
SPEED_RANGE = (1e-3, 1e6)
#: Longest pause between two frames with --realtime, s (a gap in the stamps).
MAX_PAUSE_S = 10.0


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "replay",
        help="stream a recording frame by frame through the online fusion + tracking API",
        description="Feed a recording's frames one at a time to the streaming API (association, "
                    "one-shot fusion, central tracker), as a live network would send them; "
                    "print one line per frame and a latency summary.")
    p.add_argument("recording", help="HDF5 recording (docs/FORMAT.md)")
    p.add_argument("--calibration", default=None,
                   help="calibration JSON; default: the poses stored in the recording (either "
                        "way with their covariances and clock offsets, and the /noise sigmas)")
    p.add_argument("--realtime", action="store_true",
                   help="pace the frames at the recorded frame rate")
    p.add_argument("--speed", type=float, default=None,
                   help="with --realtime (implied), play X times faster than recorded")
    p.add_argument("--mode", choices=["map", "ml"], default="map",
                   help="MAP with the paper's prior, or maximum likelihood (default %(default)s)")
    p.add_argument("--solver", type=solver_choice(("scalar", "gtsam", "vectorized")), default="scalar",
                   metavar="{scalar,gtsam,vectorized}",
                   help="the scalar solver (one frame in plain floats, GTSAM's steps, "
                        "docs/STREAMING.md), one GTSAM graph per group, or the vectorized "
                        "solver on the frame's groups (default %(default)s)")
    p.add_argument("--source", choices=["centroids", "point_cloud"], default="centroids",
                   help="detections to stream (default %(default)s)")
    p.add_argument("--gate", type=float, default=0.999,
                   help="association gate probability (default %(default)s)")
    p.add_argument("--summary", action="store_true", help="print only the summary")
    p.add_argument("-o", "--output", default=None,
                   help="write one JSON line per frame (fused targets and tracks) to this file")
    add_overwrite(p)
    p.set_defaults(func=run)


def _check_args(args) -> float | None:
    """The playback speed (None: as fast as possible); usage errors exit 2."""
    if args.output is not None and os.path.isdir(args.output):
        raise ValidationError(f"--output {args.output!r} is a directory; give a file name")
    if args.speed is None:
        return 1.0 if args.realtime else None
    if not (SPEED_RANGE[0] <= args.speed <= SPEED_RANGE[1]):
        raise ValidationError(f"--speed must be between {SPEED_RANGE[0]:g} and "
                              f"{SPEED_RANGE[1]:g} (times the recorded rate), got {args.speed!r}")
    return float(args.speed)


def _line(frame: int, u) -> str:
    if not u.ok:
        return f"frame {frame:6d} t={u.time_s:9.3f}s FLAGGED: {u.message}"
    parts = [f"frame {frame:6d} t={u.time_s:9.3f}s {len(u)} target(s), {u.success.sum()} ok"]
    for tid, x in zip(u.track_id, u.track_state):
        parts.append(f"track {tid}: ({x[0]:+.2f}, {x[1]:+.2f}) m ({x[2]:+.2f}, {x[3]:+.2f}) m/s")
    parts.append(f"{u.latency_s * 1e3:.2f} ms")
    return " | ".join(parts)


def _record(frame: int, u) -> dict:
    return {"frame": frame, "time_s": u.time_s, "ok": u.ok, "message": u.message,
            "state": u.state.tolist(), "covariance": u.covariance.tolist(),
            "status": u.status.tolist(), "track_id": u.track_id.tolist(),
            "track_state": u.track_state.tolist(), "track_covariance": u.track_covariance.tolist(),
            "latency_s": u.latency_s}


def _summary(latencies, n_frames, n_bad, n_groups, n_ok, n_tracks_max) -> str:
    lat = np.asarray(latencies) * 1e3
    med, p99 = (np.median(lat), np.percentile(lat, 99)) if lat.size else (np.nan, np.nan)
    return (f"replayed {n_frames} frames: {n_groups} fused targets ({n_ok} ok, {n_groups - n_ok} "
            f"flagged), {n_bad} frames flagged, at most {n_tracks_max} live tracks; "
            f"latency per frame median {med:.3f} ms, p99 {p99:.3f} ms")


def run(args: argparse.Namespace) -> int:
    # Deferred as in the other commands: building the parser imports no numerics or h5py.
    from mmsnap_graph._atomic import atomic_path
    from mmsnap_graph.app.runs import paper_noise, stored_calibration
    from mmsnap_graph.data.noise import GaussianPrior
    from mmsnap_graph.fusion.recording.sequence import recording_poses
    from mmsnap_graph.fusion.stream.frame_stream import FrameStream, recording_frames
    from mmsnap_graph.fusion.recording.timing import align_recording
    from mmsnap_graph.io import read_recording

    speed = _check_args(args)
    rec = read_recording(args.recording, load_cubes=False)
    cal = stored_calibration(args.recording, rec.node_names, calibration_json=args.calibration)
    cal = cal.with_default_noise(*paper_noise())
    print("\n".join(cal.text), file=sys.stderr)  # stdout: one line per frame
    if cal.time_offset_s:
        if args.source != "centroids":
            raise ValidationError("the calibration's clock offsets align centroids: use "
                                  "--source centroids")
        rec = align_recording(rec, cal.time_offset_s)
    poses = recording_poses(rec, cal.node_poses)
    stream = FrameStream(rec.node_names, poses, solver=args.solver, gate_probability=args.gate,
                         prior=GaussianPrior() if args.mode == "map" else None,
                         noise=cal.noise, pose_covariances=cal.pose_covariances)
    fill = stream.tracker_config.max_misses
    out = atomic_path(args.output) if args.output else None
    with (out if out is not None else _Null()) as path:
        sink = open(path, "w", encoding="utf-8") if path is not None else None
        try:
            stats = _play(stream, recording_frames(rec, source=args.source, fill_frames=fill),
                          speed, args.summary, sink)
        finally:
            if sink is not None:
                sink.close()
    print(_summary(*stats), file=sys.stdout)
    if args.output:
        print(f"wrote {args.output}", file=sys.stdout)
    # As `mmsnap process`: failing (exit 1) is for nothing fused at all.
    return 0 if stats[3] > 0 else 1


class _Null:
    """A context manager that gives None (no output file)."""

    def __enter__(self):
        return None

    def __exit__(self, *exc):
        return False


def _play(stream, frames, speed, summary_only, sink):
    """Push every frame (paced when ``speed`` is set); return the summary's numbers."""
    latencies, n_groups, n_ok, n_tracks_max = [], 0, 0, 0
    t0_wall = t0_rec = None
    for frame, time_s, detections in frames:
        if speed is not None:
            if t0_wall is None:
                t0_wall, t0_rec = time.monotonic(), time_s
            wait = t0_wall + (time_s - t0_rec) / speed - time.monotonic()
            if wait > 0:  # a gap in the stamps waits at most MAX_PAUSE_S
                time.sleep(min(wait, MAX_PAUSE_S))
        u = stream.push(time_s, detections)
        latencies.append(u.latency_s)
        n_groups += len(u)
        n_ok += int(np.count_nonzero(u.success))
        n_tracks_max = max(n_tracks_max, u.track_id.size)
        if not summary_only:
            print(_line(frame, u), file=sys.stdout)
        if sink is not None:
            sink.write(json.dumps(_record(frame, u)) + "\n")
    return latencies, stream.frames, stream.bad_frames, n_groups, n_ok, n_tracks_max
