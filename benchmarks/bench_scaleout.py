"""Scale-out of the per-recording pipeline on a local Dask cluster.

    python benchmarks/bench_scaleout.py [--recordings 6] [--frames 600] [--workers 1 2]
                                        [--steps process,calibrate,fuse] [--repeat 1]

Simulates the recordings once (``mmsnap simulate -c B -t random -n FRAMES
--seed k``: centroids and point clouds), then for each worker count starts a
local cluster of single-threaded worker processes, imports the library on
every worker (start-up, timed apart), and times ``run_many`` on fresh copies
of the recordings. Prints per worker count the wall time, the sum of the
per-recording times and CPU times in the workers, the peak resident memory
of each worker, and the speed-up of each count over the first: measured on
the wall clock, and from the CPU times (the first count's total CPU over the
busiest worker's CPU: what idle cores would give, load aside). Target: 2 workers at
least 1.5x faster than 1 on a 2-core machine.

The machine may be shared: the load average is printed before each run, and
the figures vary with it; compare the ratios within one run.
"""

from __future__ import annotations

import argparse
import importlib
import os
import shutil
import tempfile
import time
from collections import defaultdict
from pathlib import Path

from mmsnap_graph.app.batch import local_client, run_many
from mmsnap_graph.app.cli import main as mmsnap

#: Modules every step imports (GTSAM, scikit-learn, h5py behind them).
WARM_MODULES = ("mmsnap_graph.app.pipeline", "mmsnap_graph.calibration",
                "mmsnap_graph.fusion.recording.sequence", "mmsnap_graph.io")


def _warm_up() -> int:
    """Import the pipeline's modules in a worker (start-up cost, timed apart)."""
    for name in WARM_MODULES:
        importlib.import_module(name)
    return os.getpid()


def make_recordings(folder: Path, n: int, frames: int) -> list[Path]:
    paths = []
    for seed in range(1, n + 1):
        p = folder / f"rec{seed:02d}.h5"
        code = mmsnap(["simulate", "-c", "B", "-t", "random", "-n", str(frames),
                       "--seed", str(seed), "-o", str(p), "--no-progress"])
        if code != 0:
            raise SystemExit(f"simulate failed for seed {seed}")
        paths.append(p)
    return paths


def run_once(paths: list[Path], workers: int, steps: str, scratch: Path) -> dict:
    """One timed batch on a fresh cluster and fresh copies of the recordings."""
    out = scratch / f"out_{workers}w_{time.monotonic_ns()}"
    load = os.getloadavg()
    t0 = time.perf_counter()
    with local_client(workers) as client:
        client.run(_warm_up)
        startup = time.perf_counter() - t0
        t1 = time.perf_counter()
        summaries = run_many(paths, steps, client=client, output_dir=out)
        wall = time.perf_counter() - t1
    shutil.rmtree(out, ignore_errors=True)
    failed = [s for s in summaries if not s.success]
    if failed:
        raise SystemExit(f"{len(failed)} recording(s) failed: {failed[0].error}")
    peak: dict[str, float] = defaultdict(float)
    cpu: dict[str, float] = defaultdict(float)
    for s in summaries:
        peak[s.worker] = max(peak[s.worker], s.peak_rss_mb)
        cpu[s.worker] += s.cpu_s
    return {"workers": workers, "load": load, "startup_s": startup, "wall_s": wall,
            "work_s": sum(s.total_s for s in summaries), "peak_mb": dict(peak),
            "cpu_s": sum(cpu.values()), "busiest_cpu_s": max(cpu.values()),
            "per_recording_s": [s.total_s for s in summaries]}


def report(r: dict, base: dict | None) -> None:
    load = ", ".join(f"{v:.2f}" for v in r["load"])
    peaks = " ".join(f"{v:.0f}" for v in sorted(r["peak_mb"].values()))
    ratio = "" if base is None else (
        f"\n    speed-up x{base['wall_s'] / r['wall_s']:.2f} (wall); "
        f"x{base['busiest_cpu_s'] / r['busiest_cpu_s']:.2f} from CPU times (first count's "
        f"CPU / this count's busiest worker's CPU: the speed-up on idle cores)")
    print(f"{r['workers']} worker(s): wall {r['wall_s']:6.1f} s (start-up {r['startup_s']:.1f} s "
          f"apart), in workers {r['work_s']:6.1f} s wall / {r['cpu_s']:6.1f} s CPU, "
          f"peak RSS per worker [MiB] {peaks}   [load avg before: {load}]{ratio}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--recordings", type=int, default=6)
    ap.add_argument("--frames", type=int, default=600)
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--steps", default="process,calibrate,fuse")
    ap.add_argument("--repeat", type=int, default=1, help="runs of each worker count")
    args = ap.parse_args()
    print(f"{args.recordings} recordings x {args.frames} frames, steps {args.steps}, "
          f"{os.cpu_count()} CPUs")
    with tempfile.TemporaryDirectory(prefix="bench_scaleout_") as tmp:
        scratch = Path(tmp)
        t0 = time.perf_counter()
        paths = make_recordings(scratch, args.recordings, args.frames)
        print(f"simulated in {time.perf_counter() - t0:.1f} s")
        for rep in range(args.repeat):
            print(f"-- run {rep + 1} of {args.repeat}")
            base = None
            for w in args.workers:
                r = run_once(paths, w, args.steps, scratch)
                report(r, base)
                base = base or r


if __name__ == "__main__":
    main()
