"""Per-frame latency of the streaming API against the batch path's per-frame cost.

A simulated network of four nodes around a 7 m square (S1 and S2 face each
other, S3 and S4 face each other across the other axis), one or two walking
targets (``--targets``), centroids with the simulator's noise, MAP with the
paper's prior and noise (seeded). For each solver (``--solvers``, default
``scalar gtsam``):

- stream: :class:`mmsnap_graph.fusion.stream.frame_stream.FrameStream`, one ``push`` per
  frame (validation, association, one-shot fusion of the frame's groups,
  central tracker step), per-frame fusion with no check (:data:`PLAIN_STREAM`);
  the latency of every frame is timed (wall clock and the thread's CPU time)
  and the median, 95th and 99th percentiles are printed;
- with ``--checks``, the stream of the default configuration too (every check,
  decided at once from past frames: what ``mmsnap replay`` and ``mmsnap live``
  run);
- baseline: :func:`mmsnap_graph.fusion.recording.sequence.fuse_recording` on the whole
  recording plus :func:`mmsnap_graph.tracking.central.track_fused`, the
  total divided by the number of frames (best of ``--repeat``), with the
  solver of the same name (``vectorized`` for the stream's ``scalar`` solver:
  the fastest whole-recording path).

The stream and the baseline alternate ``--repeat`` times so that machine load
hits them alike. The script also checks the stream's fused states: equal to
``fuse_recording``'s with the same solver (to 1e-9), and for ``scalar`` equal
to ``fuse_recording``'s with ``gtsam`` to
:data:`mmsnap_graph.fusion.solvers.scalar.STATE_TOLERANCE` of each component's
sigma. ``--profile`` adds where a push's CPU time goes (median per stage:
validation, association, fusion, tracker step, the update's arrays).
Wall-clock figures on a shared machine are inflated by other processes; the
CPU time per frame is the fairer figure.

Usage::

    python benchmarks/bench_stream.py [--frames 400] [--targets 1 2] [--repeat 2] [--seed 0]
                                      [--solvers scalar gtsam vectorized] [--profile]
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

import dataclasses

from mmsnap_graph.fusion.config import PLAIN_CONFIG
from mmsnap_graph.fusion.solvers.scalar import COVARIANCE_TOLERANCE, STATE_TOLERANCE
from mmsnap_graph.fusion.options import FusionOptions
from mmsnap_graph.fusion.recording.sequence import fuse_recording
from mmsnap_graph.fusion.stream.frame_stream import STREAM_CONFIG, FrameStream, recording_frames
from mmsnap_graph.sim import simulate_recording
from mmsnap_graph.tracking.central import track_fused
from mmsnap_graph.sim import SimulationOptions

#: Four nodes around a 7 m square, each facing the centre.
NETWORK = {"S1": [0.0, 0.0, 0.0], "S2": [0.0, 7.0, np.pi],
           "S3": [-3.5, 3.5, -np.pi / 2], "S4": [3.5, 3.5, np.pi / 2]}


#: The whole-recording path each stream solver is compared with.
BASELINE = {"scalar": "vectorized", "gtsam": "gtsam", "vectorized": "vectorized"}
#: Per-frame one-shot fusion, no check: the stream's work on 80ec03d.
PLAIN_STREAM = dataclasses.replace(PLAIN_CONFIG, checks=())
#: The stages of a push timed by ``--profile``: (owner, method) of FrameStream's steps.
STAGES = {"validate": ("", "_validate"), "associate": ("_associator", "members"),
          "fuse": ("_pipeline", "solve"), "checks": ("_pipeline", "decide"),
          "tracker": ("", "_step_tracker"), "update arrays": ("", "_update")}


def _config(solver, checks=False):
    base = STREAM_CONFIG if checks else PLAIN_STREAM
    return dataclasses.replace(base, solve=FusionOptions(solver=solver))


def _timed(fn, store):
    def wrapper(*args, **kwargs):
        c0 = time.thread_time()
        try:
            return fn(*args, **kwargs)
        finally:
            store.append(time.thread_time() - c0)
    return wrapper


def _instrument(stream):
    """Time each stage of ``stream``'s pushes (instance attributes shadow the
    methods); returns ``{stage: list of CPU seconds}``."""
    times = {name: [] for name in STAGES}
    for name, (part, attr) in STAGES.items():
        owner = getattr(stream, part) if part else stream
        setattr(owner, attr, _timed(getattr(owner, attr), times[name]))
    return times


def _stream_once(rec, poses, solver, profile=False, checks=False):
    """Per-frame wall and CPU latencies (s), the fused states and covariances
    of one pass, and the stage times (``--profile``)."""
    config = _config(solver, checks)
    stream = FrameStream(rec.node_names, poses, config=config)
    frames = list(recording_frames(rec, fill_frames=stream.tracker_config.max_misses))
    stream.push(-1.0, frames[0][2])  # warm-up (imports, caches); its own time line
    stream = FrameStream(rec.node_names, poses, config=config)
    stages = _instrument(stream) if profile else None
    wall, cpu, states, covs = [], [], [], []
    for _, time_s, detections in frames:
        w0, c0 = time.perf_counter(), time.thread_time()
        u = stream.push(time_s, detections)
        cpu.append(time.thread_time() - c0)
        wall.append(time.perf_counter() - w0)
        states.append(u.state)
        covs.append(u.covariance)
    return (np.array(wall), np.array(cpu), np.concatenate(states), np.concatenate(covs),
            len(frames), stages)


def _batch_once(rec, solver):
    w0, c0 = time.perf_counter(), time.thread_time()
    config = dataclasses.replace(PLAIN_CONFIG, solve=FusionOptions(solver=solver))
    fused = fuse_recording(rec, config, progress=False)
    track_fused(fused)
    return time.perf_counter() - w0, time.thread_time() - c0, fused


def _check_states(solver, states, covs, fused, reference):
    """The stream's states against the whole-recording path's."""
    if solver != "scalar":
        assert np.allclose(states, fused.state, rtol=0, atol=1e-9), "stream != fuse_recording"
        return
    ok = reference.success
    sig = np.sqrt(np.einsum("fii->fi", reference.covariance[ok]))
    gap = np.max(np.abs(states[ok] - reference.state[ok]) / sig, initial=0.0)
    assert gap <= STATE_TOLERANCE, f"stream (scalar) != fuse_recording (gtsam): {gap:.3g} sigma"
    cov_gap = np.max(np.abs(covs[ok] - reference.covariance[ok]) / np.einsum("fi,fj->fij", sig, sig),
                     initial=0.0)
    assert cov_gap <= COVARIANCE_TOLERANCE, f"covariances differ by {cov_gap:.3g}"


def _run(n_targets, args):
    rec = simulate_recording(NETWORK, "random",
                             SimulationOptions(physics=None, n_targets=n_targets, known_poses=True),
                             levels=("centroids",), n_frames=args.frames, seed=args.seed)
    poses = np.array([NETWORK[n] for n in rec.node_names])
    gtsam = dataclasses.replace(PLAIN_CONFIG, solve=FusionOptions(solver="gtsam"))
    reference = (fuse_recording(rec, gtsam, progress=False)
                 if "scalar" in args.solvers else None)
    medians = {}
    for solver in args.solvers:
        wall, cpu, stages = [], [], {}
        best_bw = best_bc = np.inf
        for _ in range(args.repeat):
            w, c, states, covs, n_frames, st = _stream_once(rec, poses, solver, args.profile)
            wall.append(w)
            cpu.append(c)
            for name, v in (st or {}).items():
                stages.setdefault(name, []).extend(v)
            bw, bc, fused = _batch_once(rec, BASELINE[solver])
            best_bw, best_bc = min(best_bw, bw), min(best_bc, bc)
        _check_states(solver, states, covs, fused, reference)
        wall_ms, cpu_ms = np.concatenate(wall) * 1e3, np.concatenate(cpu) * 1e3
        medians[solver] = np.median(cpu_ms)
        base_w, base_c = best_bw / n_frames * 1e3, best_bc / n_frames * 1e3
        print(f"{n_targets} target(s), solver {solver:5s}: stream per frame wall median "
              f"{np.median(wall_ms):.3f} ms, p95 {np.percentile(wall_ms, 95):.3f} ms, p99 "
              f"{np.percentile(wall_ms, 99):.3f} ms; CPU median {medians[solver]:.3f} ms, p95 "
              f"{np.percentile(cpu_ms, 95):.3f} ms, p99 {np.percentile(cpu_ms, 99):.3f} ms | "
              f"fuse_recording ({BASELINE[solver]}) + track_fused per frame wall {base_w:.3f} ms, "
              f"CPU {base_c:.3f} ms | stream / that (CPU medians) {medians[solver] / base_c:.2f}x "
              f"({n_frames} frames x {args.repeat})")
        if stages:
            print("    where a push's CPU time goes (median per push, ms): " + ", ".join(
                f"{name} {np.median(v) * 1e3:.3f}" for name, v in stages.items()))
    for solver in args.solvers if args.checks else ():
        cpu = np.concatenate([_stream_once(rec, poses, solver, checks=True)[1]
                              for _ in range(args.repeat)]) * 1e3
        print(f"    with every check (delay 0), solver {solver:5s}: CPU median "
              f"{np.median(cpu):.3f} ms, p95 {np.percentile(cpu, 95):.3f} ms, p99 "
              f"{np.percentile(cpu, 99):.3f} ms; / no check {np.median(cpu) / medians[solver]:.2f}x")
    if "scalar" in medians and "gtsam" in medians:
        print(f"    stream scalar / stream gtsam (CPU medians): "
              f"{medians['scalar'] / medians['gtsam']:.2f}x")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=400)
    parser.add_argument("--targets", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--repeat", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--solvers", nargs="+", default=["scalar", "gtsam"],
                        choices=["scalar", "gtsam", "vectorized"])
    parser.add_argument("--checks", action="store_true",
                        help="also time the stream of the default configuration (every check)")
    parser.add_argument("--profile", action="store_true",
                        help="also time each stage of a push (adds ~1 us per stage)")
    args = parser.parse_args(argv)
    print(f"4 nodes, {args.frames} frames, MAP (paper prior), centroids; target: median < 1 ms "
          f"(load average {os.getloadavg()[0]:.2f} at the start)")
    for n in args.targets:
        _run(n, args)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
