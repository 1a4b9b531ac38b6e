"""``mmsnap live``: TI boards -> fused people with persistent ids, as they walk
(docs/LIVE.md).

The boards run as for ``mmsnap record`` (:mod:`.record`); their frames are
grouped on the common clock, clustered, fused and tracked frame by frame
(:class:`mmsnap_graph.app.live.driver.LiveFusion`) with the node poses of
``--calibration`` (a calibration JSON, or a recording ``mmsnap calibrate``
calibrated, whose ``/noise`` sigmas are used too). One JSON line per person
per frame goes to standard output or ``-o FILE``; ``--record REC.h5`` keeps
the raw frames and the centroids fused, which ``mmsnap replay REC.h5``
streams again to the same rows. ``--view`` / ``--view-log`` show each
board's points and the people in Foxglove or Lichtblick
(:mod:`mmsnap_graph.app.view`). The covariance self-check without truth
says on standard error whether the covariances are the right size for the
data, each time its verdict changes (``--no-self-check``: not run).
"""

from __future__ import annotations

import argparse
import sys

from mmsnap_graph._atomic import open_regular
from ..arguments import (add_fusion_arguments, add_self_check_argument, fusion_config,
                         say_self_check)
from ..file_rules import add_overwrite
from ...view.arguments import add_view_options
from .board_args import (add_board_options, board_specs, mountings, pump, report_lines,
                         session_for)


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "live", help="fuse TI boards live: people with ids as JSON lines",
        description="Run TI mmWave boards on serial ports and fuse them frame by frame with a "
                    "stored calibration (docs/LIVE.md); one JSON line per person per frame.")
    p.add_argument("--calibration", required=True,
                   help="the node poses: a calibration JSON (mmsnap calibrate --json-out) or a "
                        "calibrated recording (its poses and /noise sigmas)")
    p.add_argument("-o", "--output", default=None,
                   help="write the JSON lines to this file (default: standard output)")
    p.add_argument("--record", default=None, metavar="REC.h5",
                   help="also write the boards' frames and the centroids fused to a recording")
    add_refine_options(p)
    add_board_options(p)
    add_fusion_arguments(p, solvers=("scalar", "gtsam", "vectorized"), default_solver="scalar")
    add_view_options(p)
    add_self_check_argument(p)
    add_overwrite(p)
    p.set_defaults(func=run)


def add_refine_options(p: argparse.ArgumentParser) -> None:
    from mmsnap_graph.calibration.online_defaults import REFINE_WINDOW_S
    g = p.add_argument_group("live refinement (docs/LIVE.md, \"Refining the calibration live\")")
    g.add_argument("--refine", action=argparse.BooleanOptionalAction, default=False,
                   help="refine the poses and clock offsets as people walk, in a process of "
                        "its own, and re-calibrate a radar the decalibration monitor sees "
                        "moved; each change is a JSON line on standard error (default: off, "
                        "the poses of --calibration throughout)")
    g.add_argument("--refine-window-s", type=float, default=REFINE_WINDOW_S, metavar="SECONDS",
                   help=f"calibrate every this many seconds of frames (default "
                        f"{REFINE_WINDOW_S:g})")
    g.add_argument("--refined-calibration", default=None, metavar="FILE.json",
                   help="with --refine, write the refined calibration JSON here after each "
                        "change, atomically (an existing file needs --overwrite)")


def refine_sink(args, stream, names, poses, cal, frame_period_s):
    """The :class:`~mmsnap_graph.app.live.refine.RefineSink` of ``--refine``, or None."""
    from mmsnap_graph._atomic import check_output_path, refuse_existing
    from mmsnap_graph.errors import ValidationError
    if not args.refine:
        if args.refined_calibration is not None:
            raise ValidationError("--refined-calibration is written by --refine: give both")
        return None
    from mmsnap_graph.app.live.refine import RefineSink
    path = args.refined_calibration
    if path is not None:
        path = check_output_path(path)
        refuse_existing(path, overwrite=args.overwrite)
    return RefineSink(stream, names, poses, frame_period_s=frame_period_s,
                      covariances=cal.pose_covariances, noise=cal.noise, json_path=path,
                      window_s=args.refine_window_s,
                      log=lambda line: print(line, file=sys.stderr, flush=True))


def run(args: argparse.Namespace) -> int:
    import time

    from mmsnap_graph.app.live.driver import (LiveFusion, live_calibration, live_recording,
                                              live_stream, wall_executor)
    from mmsnap_graph.app.live.sinks import CentroidLog, JsonLinesSink, LatencyLog, SelfCheckSink
    from mmsnap_graph.app.view.arguments import view_sink
    from mmsnap_graph.fusion.config import LearnedWalls
    from mmsnap_graph.io import write_recording
    from mmsnap_graph.io.ti.serial.session import FrameCollector
    config = fusion_config(args)
    specs = board_specs(args)
    names = [s.name for s in specs]
    poses, cal = live_calibration(args.calibration, names)
    print("\n".join(cal.text), file=sys.stderr)
    if cal.time_offset_s:
        print("the calibration's clock offsets are not applied: the boards share the host "
              "clock (replay the recording with --no-time-offsets)", file=sys.stderr)
    session = session_for(args, specs)
    mounts = mountings(args, specs, session.timing)
    # The coverage check's reach: each board's .cfg maximum range (how far it
    # looks), written with --record for replay and fuse; a board without a
    # .cfg: its farthest centroid so far.
    reach = {n: t.max_range_m for n, t in session.timing.items() if t.max_range_m is not None}
    config = config.with_coverage_reach(reach)
    # The learned walls in a worker process beside the stream (the same rows
    # as learned in line: LearnedWalls.apply_after_frames).
    walls = config.check(LearnedWalls)
    learner = wall_executor() if walls is not None and walls.apply_after_frames else None
    stream = live_stream(names, poses, frame_period_s=session.frame_period_s, config=config,
                         noise=cal.noise, pose_covariances=cal.pose_covariances,
                         range_offset_m=cal.range_offset_m, wall_executor=learner)
    out = sys.stdout if args.output is None else open_regular(args.output)
    json_sink, centroids, latency = JsonLinesSink(out), CentroidLog(), LatencyLog()
    collector = FrameCollector(names, session.frame_period_s, t0_s=session.t0_s)
    # The view after the latency log: what it costs is not the JSON line's latency.
    view = view_sink(args, names, poses,
                     time_origin_s=time.time() - time.monotonic() + session.t0_s)
    # The refinement after the latency log too: it only hands the centroids on.
    refine = refine_sink(args, stream, names, poses, cal, session.frame_period_s)
    # The covariance self-check after the latency log too: a verdict on
    # standard error each time it changes, the whole run's at the end.
    check = None if args.no_self_check else SelfCheckSink(
        frame_period_s=session.frame_period_s, prior=config.prior, command="live",
        log=lambda line: print(line, file=sys.stderr, flush=True))
    sinks = [json_sink, centroids, latency] + [s for s in (view, refine, check) if s is not None]
    live = LiveFusion(names, stream, mounting=mounts, frame_period_s=session.frame_period_s,
                      t0_s=session.t0_s, sinks=sinks, height_band_m=args.height_band)

    def on_frame(frame):
        collector.add(frame)
        live.add(frame)

    try:
        with session:
            print(f"live: {len(specs)} board(s) at {1 / session.frame_period_s:g} fps (Ctrl-C "
                  "ends it)", file=sys.stderr)
            why = pump(session, on_frame, args.duration,
                       on_idle=lambda: live.poll(time.monotonic()))
        live.flush()
    finally:
        if out is not sys.stdout:
            out.close()
        if view is not None:
            view.close()
        if refine is not None:
            refine.close()
        if learner is not None:
            learner.shutdown(cancel_futures=True)
    print("\n".join(report_lines(session)), file=sys.stderr)
    if args.view_log:
        print(f"wrote {args.view_log} (open it in Foxglove or Lichtblick)", file=sys.stderr)
    print(f"stopped after {why}: {latency.summary()}; {json_sink.lines} person rows; "
          f"{live.late} board frame(s) too late for their slot; the queue held at most "
          f"{session.max_queued} board frame(s) (bound {session.frames.maxsize})", file=sys.stderr)
    if refine is not None:
        print(refine.report(), file=sys.stderr)
    if check is not None:
        say_self_check("live", check.report(), sys.stderr)
    if args.record:
        rec = live_recording(collector, centroids, dict(zip(names, poses)), mounting=mounts,
                             height_band_m=args.height_band, reach_m=reach)
        print(f"wrote {write_recording(args.record, rec, overwrite=args.overwrite)}",
              file=sys.stderr)
    return 0
