"""Where the demo's time goes, and why its six runs start from point clouds.

Measures, in one run:

- the demo's six configuration x trajectory runs from the point-cloud level
  (torso DBSCAN -> EKF -> calibration -> fusion, sample recordings when
  present, else simulated), 600 frames each, without figures;
- raw-cube synthesis and the full per-node chain on ``--cube-frames`` frames
  of two nodes, per node-frame;

and prints the estimated time of the same six runs from raw cubes (6 runs x
2 nodes x 600 frames of synthesis + chain, plus the point-cloud-level work)
and its ratio to the point-cloud level: the baseline of the ratio is the
demo as it runs.

Usage: ``python benchmarks/bench_demo.py [--cube-frames 20] [--frames 600]``
"""

from __future__ import annotations

import argparse
import time

from mmsnap_graph.app import demo
from mmsnap_graph.app.pipeline import process_recording
from mmsnap_graph.sim import simulate_recording
from mmsnap_graph.sim import CLEAN


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cube-frames", type=int, default=20)
    ap.add_argument("--frames", type=int, default=600)
    args = ap.parse_args()

    data = demo.find_sample_data()
    t0 = time.perf_counter()
    res = demo.run_demo(demo.DemoConfig(n_frames=args.frames, cube_frames=0), data_dir=data)
    t_runs = time.perf_counter() - t0
    n_runs = len(res.sources)

    t0 = time.perf_counter()
    rec = simulate_recording("C", "straight", CLEAN, levels=("cube",), n_frames=args.cube_frames,
                             seed=1)
    t_synth = time.perf_counter() - t0
    t0 = time.perf_counter()
    process_recording(rec)
    t_chain = time.perf_counter() - t0
    node_frames = 2 * args.cube_frames
    per_synth = t_synth / node_frames
    per_chain = t_chain / node_frames
    total_nf = n_runs * 2 * args.frames
    est = total_nf * (per_synth + per_chain) + t_runs

    print(f"data: {'sample recordings in ' + str(data) if data else 'simulated'}")
    print(f"{n_runs} runs x {args.frames} frames from point clouds: {t_runs:.1f} s "
          f"({1e3 * t_runs / (n_runs * args.frames):.1f} ms per run-frame)")
    print(f"raw cubes, per node-frame ({node_frames} node-frames): synthesis {1e3 * per_synth:.1f} ms, "
          f"chain (FFTs, OS-CFAR, DBSCAN, EKF) {1e3 * per_chain:.1f} ms")
    print(f"the same {n_runs} runs from raw cubes ({total_nf} node-frames): ~{est:.0f} s estimated")
    print(f"ratio raw-cube level / point-cloud level: {est / t_runs:.1f}x")


if __name__ == "__main__":
    main()
