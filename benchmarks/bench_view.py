"""What the live view costs: the Foxglove log per frame against the stream's
own per-frame cost, and the viewers' import times.

Frames: a simulated walk of ``--people`` people before four radars (the
network of bench_stream.py), each radar's point cloud (``--points`` points a
frame) and its centroids, streamed through
:class:`~mmsnap_graph.fusion.stream.frame_stream.FrameStream`. Timed, per
frame (median, p99; wall clock and the thread's CPU time):

- stream: ``FrameStream.push`` (association, fusion, tracker);
- foxglove: :class:`mmsnap_graph.app.view.foxglove_log.FoxgloveView.write`
  of the frame to an MCAP file (``--serve``: also to a WebSocket server on
  loopback with no client);
- rerun (when ``rerun-sdk`` is installed, it is not a dependency): the same
  content logged with Rerun to an ``.rrd`` file: the points, the ellipses,
  arrows and labels of the people, their histories, the radars.

Import times: ``python -c "import foxglove"`` (and ``import rerun``) in a
fresh process, best of 3.

Usage::

    python benchmarks/bench_view.py [--frames 400] [--people 2] [--points 30] [--serve]
"""

from __future__ import annotations

import argparse
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from mmsnap_graph.app.live.driver import LiveFrame
from mmsnap_graph.app.view.scene import (TrackHistory, covariance_ellipse, detections_xy,
                                         field_of_view)
from mmsnap_graph.data.recording import Detections
from mmsnap_graph.fusion.stream.frame_stream import FrameStream
from mmsnap_graph.sim import SimulationOptions, simulate_recording

NETWORK = {"S1": [0.0, 0.0, 0.0], "S2": [0.0, 7.0, np.pi], "S3": [3.5, 3.5, np.pi / 2],
           "S4": [-3.5, 3.5, -np.pi / 2]}


def frames(n_frames, n_people, n_points, seed=0):
    """(LiveFrame-making inputs) of a simulated walk: per frame the time,
    each radar's centroids and a cloud of ``n_points`` around them."""
    rec = simulate_recording(NETWORK, "random", SimulationOptions(physics=None, n_targets=n_people,
                                                                  known_poses=True),
                             levels=("centroids",), n_frames=n_frames, seed=seed)
    rng = np.random.default_rng(seed)
    out = []
    for f in range(n_frames):
        cents, points = {}, {}
        for name in rec.node_names:
            c = rec.nodes[name].centroids
            z = c.measurements[c.frame == f]
            cents[name] = z
            k = rng.integers(0, max(len(z), 1), n_points)
            base = z[k] if len(z) else np.tile([3.0, 0.0, 0.0], (n_points, 1))
            cloud = base + rng.normal(0, [0.1, 0.05, 0.1], (n_points, 3))
            points[name] = Detections(frame=np.full(n_points, f), range_m=np.abs(cloud[:, 0]),
                                      omega_rad=np.clip(cloud[:, 1], -3, 3),
                                      doppler_mps=cloud[:, 2], snr_db=np.full(n_points, 20.0))
        out.append((f, f * rec.frame_period_s, points, cents))
    return rec, out


def _stats(label, wall, cpu):
    w, c = np.array(wall) * 1e3, np.array(cpu) * 1e3
    print(f"{label:>10}: wall median {np.median(w):.3f} ms, p99 {np.percentile(w, 99):.3f} ms; "
          f"CPU median {np.median(c):.3f} ms, p99 {np.percentile(c, 99):.3f} ms")


def _timed(fn):
    w0, c0 = time.perf_counter(), time.thread_time()
    out = fn()
    return out, time.perf_counter() - w0, time.thread_time() - c0


def run_foxglove(rec, data, serve):
    from mmsnap_graph.app.view.foxglove_log import FoxgloveView, ViewOptions

    names = rec.node_names
    poses = np.array([NETWORK[n] for n in names])
    stream = FrameStream(names, poses)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bench.mcap"
        view = FoxgloveView(names, poses, ViewOptions(log_path=path, serve=serve, port=0))
        timing = {"stream": ([], []), "foxglove": ([], []), "lives": []}
        for f, t, points, cents in data:
            u, w, c = _timed(lambda: stream.push(t, cents))
            timing["stream"][0].append(w)
            timing["stream"][1].append(c)
            live = LiveFrame(frame=f, time_s=t, boards=tuple(names), points=points,
                             centroids=cents, update=u, last_byte_s=0.0, done_s=0.0)
            timing["lives"].append(live)
            _, w, c = _timed(lambda: view.write(live))
            timing["foxglove"][0].append(w)
            timing["foxglove"][1].append(c)
        view.close()
        size = path.stat().st_size
    _stats("stream", *timing["stream"])
    _stats("foxglove", *timing["foxglove"])
    print(f"{'':>10}  MCAP {size / len(data) / 1e3:.1f} kB per frame")
    return timing["lives"], poses


def run_rerun(lives, names, poses):
    """The same scene with Rerun (2D archetypes), to an .rrd file."""
    import rerun as rr

    wall, cpu = [], []
    hist = TrackHistory()
    with tempfile.TemporaryDirectory() as tmp:
        rr.init("mmsnap_bench", spawn=False)
        rr.save(str(Path(tmp) / "bench.rrd"))
        for live in lives:
            def log():
                rr.set_time("time", duration=live.time_s)
                if live.frame % 20 == 0:
                    rr.log("radars", rr.LineStrips2D([field_of_view(p) for p in poses],
                                                     labels=list(names)))
                for i, name in enumerate(names):
                    rr.log(f"points/{name}", rr.Points2D(detections_xy(live.points[name],
                                                                       poses[i])))
                u = live.update
                xs = np.asarray(u.track_state).reshape(-1, 4)
                ps = np.asarray(u.track_covariance).reshape(-1, 4, 4)
                hist.update(live.time_s, u.track_id, xs[:, :2])
                rr.log("people/ellipses", rr.LineStrips2D(
                    [covariance_ellipse(x[:2], p[:2, :2]) for x, p in zip(xs, ps)],
                    labels=[str(i) for i in u.track_id]))
                rr.log("people/velocity", rr.Arrows2D(origins=xs[:, :2], vectors=xs[:, 2:]))
                rr.log("people/tracks", rr.LineStrips2D(list(hist.lines().values())))
            _, w, c = _timed(log)
            wall.append(w)
            cpu.append(c)
        rr.disconnect()
    _stats("rerun", wall, cpu)


def import_time(module):
    best = math.inf
    for _ in range(3):
        t0 = time.perf_counter()
        done = subprocess.run([sys.executable, "-c", f"import {module}"], capture_output=True)
        if done.returncode:
            return None
        best = min(best, time.perf_counter() - t0)
    base = min(_python_start() for _ in range(3))
    return best - base


def _python_start():
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", "pass"], check=True)
    return time.perf_counter() - t0


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--frames", type=int, default=400)
    p.add_argument("--people", type=int, default=2)
    p.add_argument("--points", type=int, default=30, help="points per radar per frame")
    p.add_argument("--serve", action="store_true", help="also serve on loopback")
    args = p.parse_args(argv)
    rec, data = frames(args.frames, args.people, args.points)
    print(f"{args.frames} frames, 4 radars x {args.points} points, {args.people} people")
    lives, poses = run_foxglove(rec, data, args.serve)
    try:
        run_rerun(lives, rec.node_names, poses)
    except ImportError:
        print(f"{'rerun':>10}: not installed (pip install rerun-sdk to compare)")
    for module in ("foxglove", "rerun"):
        t = import_time(module)
        print(f"import {module}: " + ("not installed" if t is None else f"{t:.3f} s beyond "
                                      "the interpreter's start"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
