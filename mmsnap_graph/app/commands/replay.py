"""``mmsnap replay``: stream a recording frame by frame through the online API
(:class:`mmsnap_graph.fusion.stream.frame_stream.FrameStream`, docs/STREAMING.md).

Fuses with what ``mmsnap calibrate`` stored, read as ``mmsnap fuse`` reads it
(:func:`mmsnap_graph.app.runs.stored_calibration`: poses or ``--calibration``,
their covariances, the clock offsets, the ``/noise`` sigmas), said on stderr.
Prints one line per frame (or only the summary with ``--summary``); with
``--realtime`` the frames are paced at the recorded frame rate (``--speed``
times faster). Writes nothing unless ``--output`` is given (one JSON object
per frame). The covariance self-check without truth (docs/ROBUST.md) runs
on the streamed rows: its verdict on stderr when it changes, as one JSON line
``{"type": "self_check", "frame": N, "self_check": {...}}``, the loud sentence when it fails, and its
final line after the summary (``--no-self-check``: none of it). ``--view`` / ``--view-log`` show the frames in Foxglove or
Lichtblick (:mod:`mmsnap_graph.app.view`; ``--view`` plays at the recorded
rate unless ``--speed`` says otherwise).
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

from ..view.arguments import add_view_options

from .arguments import add_calibration_arguments, add_fusion_arguments, \
    add_self_check_argument, calibration_for, config_text, fusion_config, say_self_check


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
    p.add_argument("--realtime", action="store_true",
                   help="pace the frames at the recorded frame rate")
    p.add_argument("--speed", type=float, default=None,
                   help="with --realtime (implied), play X times faster than recorded")
    p.add_argument("--delay", type=int, default=0, metavar="FRAMES",
                   help="decide each frame this many frames after it arrived (default 0: at "
                        "once, the checks from past frames only; the checks' look-around, 9 "
                        "frames, gives the rows of `mmsnap fuse`; docs/STREAMING.md)")
    add_calibration_arguments(p)
    add_fusion_arguments(p, solvers=("scalar", "gtsam", "vectorized"), default_solver="scalar")
    p.add_argument("--summary", action="store_true", help="print only the summary")
    p.add_argument("-o", "--output", default=None,
                   help="write one JSON line per frame (fused targets and tracks) to this file")
    add_self_check_argument(p)
    add_view_options(p)
    add_overwrite(p)
    p.set_defaults(func=run)


def _check_args(args) -> float | None:
    """The playback speed (None: as fast as possible); usage errors exit 2."""
    if args.output is not None and os.path.isdir(args.output):
        raise ValidationError(f"--output {args.output!r} is a directory; give a file name")
    if args.delay < 0:
        raise ValidationError(f"--delay must be >= 0 frames, got {args.delay}")
    if args.speed is None:  # a live view is watched at the recorded rate
        return 1.0 if args.realtime or args.view else None
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


def _record(frame: int, u, rows) -> dict:
    return {"frame": frame, "time_s": u.time_s, "ok": u.ok, "message": u.message,
            "state": u.state.tolist(), "covariance": u.covariance.tolist(),
            "status": u.status.tolist(), "detection_index": rows.tolist(),
            "track_id": u.track_id.tolist(),
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
    from mmsnap_graph.fusion.recording.coverage import coverage_reach_m
    from mmsnap_graph.fusion.recording.sequence import calibrated_recording, recording_poses
    from mmsnap_graph.fusion.stream.frame_stream import FrameStream, recording_frames
    from mmsnap_graph.app.live.sinks import SelfCheckSink
    from mmsnap_graph.app.view.arguments import view_sink
    from mmsnap_graph.io import read_recording

    speed = _check_args(args)
    config = fusion_config(args)
    rec = read_recording(args.recording, load_cubes=False)
    cal = calibration_for(args, args.recording, rec.node_names, config)
    print("\n".join(cal.text), file=sys.stderr)  # stdout: one line per frame
    print(config_text(config), file=sys.stderr)
    network = cal.network_calibration()
    # The coverage check's reach as `mmsnap fuse` takes it: the one the file
    # declares (mmsnap live's), else every detection of the file.
    config = config.with_coverage_reach(coverage_reach_m(rec))
    # The clock and range offsets as the recording drivers apply them (one place).
    rec = calibrated_recording(rec, network, config.association.source)
    poses = recording_poses(rec, network.node_poses)
    stream = FrameStream(rec.node_names, poses, config=config, noise=cal.noise,
                         pose_covariances=cal.pose_covariances, delay_frames=args.delay,
                         tracker=_tracker(rec))
    fill = stream.tracker_config.max_misses
    frames = recording_frames(rec, source=config.association.source, fill_frames=fill)
    out = atomic_path(args.output) if args.output else None
    view = view_sink(args, rec.node_names, poses,
                     time_origin_s=float(rec.metadata.get("time_origin_s", 0.0)))
    check = None if args.no_self_check else SelfCheckSink(
        frame_period_s=rec.frame_period_s, prior=config.prior, command="replay",
        log=lambda line: print(line, file=sys.stderr))
    with (out if out is not None else _Null()) as path:
        sink = open(path, "w", encoding="utf-8") if path is not None else None
        try:
            stats = _play(stream, frames, _file_rows(rec, config.association.source), speed,
                          args.summary, sink, view, check)
        finally:
            if sink is not None:
                sink.close()
            if view is not None:
                view.close()
    if args.view_log:
        print(f"wrote {args.view_log} (open it in Foxglove or Lichtblick)", file=sys.stdout)
    print(_summary(*stats), file=sys.stdout)
    if check is not None:
        say_self_check("replay", check.report(), sys.stderr)
    if args.output:
        print(f"wrote {args.output}", file=sys.stdout)
    # As `mmsnap process`: failing (exit 1) is for nothing fused at all.
    return 0 if stats[3] > 0 else 1


def _tracker(rec):
    """The central tracker's settings at the recording's frame period."""
    from mmsnap_graph.tracking.central import CentralConfig

    return CentralConfig(frame_period_s=rec.frame_period_s)


def _file_rows(rec, source):
    """``rows(frame, members (G, N)) -> (G, N)``: each member's row in the
    recording's detections (as ``/fused``'s ``detection_index``), from its row
    in the frame's detections as :func:`recording_frames` gives them."""
    per_node = []
    for name in rec.node_names:
        d = getattr(rec.nodes[name], source)
        frames = np.zeros(0, np.int64) if d is None else np.asarray(d.frame)
        order = np.argsort(frames, kind="stable")
        per_node.append((frames[order], order))

    def rows(frame, members):
        out = np.asarray(members).copy()
        for n, (frames, order) in enumerate(per_node):
            lo = np.searchsorted(frames, frame)
            has = out[:, n] >= 0
            out[has, n] = order[lo + out[has, n]]
        return out
    return rows


class _Null:
    """A context manager that gives None (no output file)."""

    def __enter__(self):
        return None

    def __exit__(self, *exc):
        return False


def _play(stream, frames, file_rows, speed, summary_only, sink, view=None, check=None):
    """Push every frame (paced when ``speed`` is set), each decided frame to
    ``view`` too (a :class:`~mmsnap_graph.app.live.driver.FusedSink`); return
    the summary's numbers."""
    from mmsnap_graph.app.live.driver import replayed_frame

    latencies, n_groups, n_ok, n_tracks_max = [], 0, 0, 0
    t0_wall = t0_rec = None
    numbers = {}  # (frame number, time, detections) of each pushed frame, by its index

    def show(u):
        nonlocal n_groups, n_ok, n_tracks_max
        frame, time_s, detections = numbers.pop(u.index)
        latencies.append(u.latency_s)
        n_groups += len(u)
        n_ok += int(np.count_nonzero(u.success))
        n_tracks_max = max(n_tracks_max, u.track_id.size)
        if not summary_only:
            print(_line(frame, u), file=sys.stdout)
        if sink is not None:
            sink.write(json.dumps(_record(frame, u, file_rows(frame, u.members))) + "\n")
        if view is not None:
            view.write(replayed_frame(frame, time_s, detections, u))
        if check is not None:
            check.add(frame, u)

    for frame, time_s, detections in frames:
        if speed is not None:
            if t0_wall is None:
                t0_wall, t0_rec = time.monotonic(), time_s
            wait = t0_wall + (time_s - t0_rec) / speed - time.monotonic()
            if wait > 0:  # a gap in the stamps waits at most MAX_PAUSE_S
                time.sleep(min(wait, MAX_PAUSE_S))
        numbers[stream.frames] = (frame, time_s, detections)
        for u in stream.feed(time_s, detections):
            show(u)
    for u in stream.flush():
        show(u)
    return latencies, stream.frames, stream.bad_frames, n_groups, n_ok, n_tracks_max
