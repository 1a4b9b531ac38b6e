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
(:mod:`mmsnap_graph.app.view`).
"""

from __future__ import annotations

import argparse
import sys

from ..arguments import add_fusion_arguments, fusion_config
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
    add_board_options(p)
    add_fusion_arguments(p, solvers=("scalar", "gtsam", "vectorized"), default_solver="scalar")
    add_view_options(p)
    add_overwrite(p)
    p.set_defaults(func=run)


def _calibration(path: str, names):
    """(poses (N, 3), noise) of ``--calibration``."""
    import numpy as np

    from mmsnap_graph.app.runs import paper_noise, stored_calibration
    from mmsnap_graph.errors import CalibrationError
    from mmsnap_graph.io import read_recording
    from mmsnap_graph.io.calibration import load_calibration_poses
    if str(path).lower().endswith(".json"):
        poses = load_calibration_poses(path)
        noise = paper_noise()[0]
    else:
        cal = stored_calibration(path, names).with_default_noise(*paper_noise())
        stored = read_recording(path, load_cubes=False).node_poses()
        poses = dict(cal.node_poses) if cal.node_poses else stored
        noise = cal.noise
    missing = [n for n in names if poses.get(n) is None]
    if missing:
        raise CalibrationError(f"--calibration {path} has no pose for board(s) {missing}")
    return np.array([poses[n] for n in names], dtype=float), noise


def run(args: argparse.Namespace) -> int:
    import time

    from mmsnap_graph.app.live.driver import LiveFusion, live_recording, live_stream
    from mmsnap_graph.app.live.sinks import CentroidLog, JsonLinesSink, LatencyLog
    from mmsnap_graph.app.view.arguments import view_sink
    from mmsnap_graph.io import write_recording
    from mmsnap_graph.io.ti.serial.session import FrameCollector
    config = fusion_config(args)
    specs = board_specs(args)
    names = [s.name for s in specs]
    poses, noise = _calibration(args.calibration, names)
    session = session_for(args, specs)
    mounts = mountings(args, specs, session.timing)
    stream = live_stream(names, poses, frame_period_s=session.frame_period_s, config=config,
                         noise=noise)
    out = sys.stdout if args.output is None else open(args.output, "w", encoding="utf-8")
    json_sink, centroids, latency = JsonLinesSink(out), CentroidLog(), LatencyLog()
    collector = FrameCollector(names, session.frame_period_s)
    # The view after the latency log: what it costs is not the JSON line's latency.
    view = view_sink(args, names, poses,
                     time_origin_s=time.time() - time.monotonic() + session.t0_s)
    sinks = [json_sink, centroids, latency] + ([view] if view is not None else [])
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
    print("\n".join(report_lines(session)), file=sys.stderr)
    if args.view_log:
        print(f"wrote {args.view_log} (open it in Foxglove or Lichtblick)", file=sys.stderr)
    print(f"stopped after {why}: {latency.summary()}; {json_sink.lines} person rows; "
          f"{live.late} board frame(s) too late for their slot", file=sys.stderr)
    if args.record:
        rec = live_recording(collector, centroids, dict(zip(names, poses)), mounting=mounts,
                             height_band_m=args.height_band)
        print(f"wrote {write_recording(args.record, rec, overwrite=args.overwrite)}",
              file=sys.stderr)
    return 0
