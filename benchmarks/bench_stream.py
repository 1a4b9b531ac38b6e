"""Per-frame latency of the streaming API against the batch path's per-frame cost.

A simulated network of four nodes around a 7 m square (S1 and S2 face each
other, S3 and S4 face each other across the other axis), one or two walking
targets (``--targets``), centroids with the simulator's noise, MAP with the
paper's prior and noise (seeded). For each solver:

- stream: :class:`mmsnap_graph.fusion.stream.FrameStream`, one ``push`` per
  frame (validation, association, one-shot fusion of the frame's groups,
  central tracker step); the latency of every frame is timed (wall clock and
  the thread's CPU time) and the median and 99th percentile are printed;
- baseline: :func:`mmsnap_graph.fusion.sequence.fuse_recording` on the whole
  recording plus :func:`mmsnap_graph.tracking.central.track_fused`, the
  total divided by the number of frames (best of ``--repeat``).

The stream and the baseline alternate ``--repeat`` times so that machine load
hits them alike. The script also checks that the stream's fused states equal
the batch path's. Wall-clock figures on a shared machine are inflated by other
processes; the CPU time per frame is the fairer figure.

Usage::

    python benchmarks/bench_stream.py [--frames 400] [--targets 1 2] [--repeat 2] [--seed 0]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from mmsnap_graph.fusion.sequence import fuse_recording
from mmsnap_graph.fusion.stream import FrameStream, recording_frames
from mmsnap_graph.sim import simulate_recording
from mmsnap_graph.tracking.central import track_fused

#: Four nodes around a 7 m square, each facing the centre.
NETWORK = {"S1": [0.0, 0.0, 0.0], "S2": [0.0, 7.0, np.pi],
           "S3": [-3.5, 3.5, -np.pi / 2], "S4": [3.5, 3.5, np.pi / 2]}


def _stream_once(rec, poses, solver):
    """Per-frame wall and CPU latencies (s) and the fused states of one pass."""
    stream = FrameStream(rec.node_names, poses, solver=solver)
    frames = list(recording_frames(rec, fill_frames=stream.tracker_config.max_misses))
    stream.push(-1.0, frames[0][2])  # warm-up (imports, caches); its own time line
    stream = FrameStream(rec.node_names, poses, solver=solver)
    wall, cpu, states = [], [], []
    for _, time_s, detections in frames:
        w0, c0 = time.perf_counter(), time.thread_time()
        u = stream.push(time_s, detections)
        cpu.append(time.thread_time() - c0)
        wall.append(time.perf_counter() - w0)
        states.append(u.state)
    return np.array(wall), np.array(cpu), np.concatenate(states), len(frames)


def _batch_once(rec, solver):
    w0, c0 = time.perf_counter(), time.thread_time()
    fused = fuse_recording(rec, solver=solver, progress=False)
    track_fused(fused)
    return time.perf_counter() - w0, time.thread_time() - c0, fused


def _run(n_targets, args):
    rec = simulate_recording(NETWORK, "random", levels=("centroids",), n_frames=args.frames,
                             n_targets=n_targets, known_poses=True, seed=args.seed)
    poses = np.array([NETWORK[n] for n in rec.node_names])
    for solver in ("gtsam", "batch"):
        wall, cpu = [], []
        best_bw = best_bc = np.inf
        for _ in range(args.repeat):
            w, c, states, n_frames = _stream_once(rec, poses, solver)
            wall.append(w)
            cpu.append(c)
            bw, bc, fused = _batch_once(rec, solver)
            best_bw, best_bc = min(best_bw, bw), min(best_bc, bc)
        assert np.allclose(states, fused.state, rtol=0, atol=1e-9), "stream != fuse_recording"
        wall_ms, cpu_ms = np.concatenate(wall) * 1e3, np.concatenate(cpu) * 1e3
        base_w, base_c = best_bw / n_frames * 1e3, best_bc / n_frames * 1e3
        print(f"{n_targets} target(s), solver {solver:5s}: stream per frame wall median "
              f"{np.median(wall_ms):.3f} ms, p99 {np.percentile(wall_ms, 99):.3f} ms; "
              f"CPU median {np.median(cpu_ms):.3f} ms, p99 {np.percentile(cpu_ms, 99):.3f} ms | "
              f"batch fuse_recording + track_fused per frame wall {base_w:.3f} ms, CPU "
              f"{base_c:.3f} ms | stream / batch (CPU medians) {np.median(cpu_ms) / base_c:.2f}x "
              f"({n_frames} frames x {args.repeat})")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=400)
    parser.add_argument("--targets", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--repeat", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    print(f"4 nodes, {args.frames} frames, MAP (paper prior), centroids; target: median < 1 ms")
    for n in args.targets:
        _run(n, args)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
