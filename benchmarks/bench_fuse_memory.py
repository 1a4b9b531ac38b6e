"""Peak memory of fusing a long recording: the whole-file path against the
chunked one (issue 13: 1 hour of 10 nodes under 500 MB).

A recording of 10 nodes on a circle of radius 6 m, each facing the centre,
one walking target, centroids only, 150 ms frames: 2,400 frames are
simulated once (:func:`mmsnap_graph.sim.simulate_recording`) and repeated
along the time axis (frame numbers shifted) to 1/4, 1/2 and 1 hour (6,000,
12,000 and 24,000 frames). For each length and each path, a fresh Python
process fuses the file (MAP, batch solver, the paper's prior and noise) and
reports its peak resident set size (``VmHWM`` of ``/proc/self/status``, Linux) and, with
``--tracemalloc``, the peak of Python allocations:

- whole: what ``mmsnap fuse`` did before chunked reading:
  :func:`~mmsnap_graph.io.read_recording` +
  :func:`~mmsnap_graph.fusion.recording.sequence.fuse_recording` +
  :func:`~mmsnap_graph.io.write_fused`;
- chunked: ``mmsnap fuse`` (:func:`mmsnap_graph.app.chunked_fuse.fuse_file`,
  windows of ``--window`` frames).

The ratio whole / chunked is printed per length, with both paths' wall time.
The baseline of a process that only imports the packages is printed first.

Usage::

    python benchmarks/bench_fuse_memory.py [--hours 0.25 0.5 1] [--window 2000] [--tracemalloc]
                                            [--paths whole chunked]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from mmsnap_graph.sim import SimulationOptions

FRAME_PERIOD_S = 0.15
BASE_FRAMES = 2400

#: Runs in a fresh process: argv = path, mode ("import" | "whole" | "chunked" | "cli"),
#: window, trace. "whole" and "chunked" run the library's per-frame fusion (no robust fit,
#: the learned walls on in "chunked": what both did by default on 80ec03d); "cli" runs
#: ``mmsnap fuse REC`` with its defaults (every check).
CHILD = r"""
import json, sys, time, tracemalloc
path, mode, window, trace = sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4] == "1"
import h5py, numpy, gtsam  # noqa: F401  the same imports in every mode
from mmsnap_graph.fusion.recording.sequence import fuse_recording
from mmsnap_graph.io import read_recording, write_fused
if trace:
    tracemalloc.start()
t0 = time.perf_counter()
try:
    from mmsnap_graph.fusion.config import PLAIN_CONFIG, LearnedWalls, SplitCheck
    import dataclasses
    whole = dict(config=PLAIN_CONFIG)
    chunked = dict(config=dataclasses.replace(PLAIN_CONFIG, checks=(SplitCheck(), LearnedWalls())))
except ImportError:  # 80ec03d: the defaults were these
    whole = chunked = {}
if mode == "whole":
    rec = read_recording(path, load_cubes=False)
    fused = fuse_recording(rec, progress=False, **whole)
    write_fused(path, fused)
    rows = len(fused)
elif mode == "chunked":
    from mmsnap_graph.app.chunked_fuse import fuse_file
    rows = fuse_file(path, window_frames=window, progress=False, **chunked).n_rows
elif mode == "cli":
    from mmsnap_graph.app.cli import main
    import contextlib, io, re
    with contextlib.redirect_stdout(io.StringIO()) as out:
        assert main(["fuse", path, "--no-progress", "--max-flagged", "1"]) == 0
    rows = int(re.search(r"^fused (\d+) targets", out.getvalue(), re.M).group(1))
else:
    rows = 0
wall = time.perf_counter() - t0
peak_py = tracemalloc.get_traced_memory()[1] if trace else 0
# VmHWM: this process's own peak (ru_maxrss would keep the parent's across exec).
with open("/proc/self/status") as f:
    rss_kib = next(int(l.split()[1]) for l in f if l.startswith("VmHWM:"))
print(json.dumps({"rows": rows, "wall_s": wall, "rss_mb": rss_kib / 1024, "py_mb": peak_py / 2**20}))
"""


def _network() -> dict:
    angles = np.linspace(0.0, 2 * np.pi, 10, endpoint=False)
    return {f"S{i + 1}": [6 * np.cos(a), 6 * np.sin(a), float(np.angle(np.exp(1j * (a + np.pi / 2))))]
            for i, a in enumerate(angles)}


def make_recording(path: Path, n_frames: int, base) -> None:
    """``base`` (a simulated Recording) repeated along time to ``n_frames``."""
    from dataclasses import replace

    from mmsnap_graph.data.recording import Detections, Recording
    from mmsnap_graph.io import write_recording

    reps = -(-n_frames // BASE_FRAMES)
    nodes = {}
    for name in base.node_names:
        c = base.nodes[name].centroids
        frame = np.concatenate([c.frame + k * BASE_FRAMES for k in range(reps)])
        keep = frame < n_frames
        tile = lambda a: np.tile(a, reps)[keep]  # noqa: E731
        det = Detections(frame=frame[keep], range_m=tile(c.range_m), omega_rad=tile(c.omega_rad),
                         doppler_mps=tile(c.doppler_mps),
                         target_id=None if c.target_id is None else tile(c.target_id))
        nodes[name] = replace(base.nodes[name], centroids=det)
    write_recording(path, Recording(frame_period_s=FRAME_PERIOD_S, nodes=nodes,
                                    metadata={"benchmark": "bench_fuse_memory"}), overwrite=True)


def run_child(path: Path, mode: str, window: int, trace: bool) -> dict:
    out = subprocess.run([sys.executable, "-c", CHILD, str(path), mode, str(window),
                          "1" if trace else "0"], capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hours", type=float, nargs="+", default=[0.25, 0.5, 1.0])
    parser.add_argument("--window", type=int, default=2000)
    parser.add_argument("--tracemalloc", action="store_true")
    parser.add_argument("--paths", nargs="+", choices=["whole", "chunked", "cli"],
                        default=["whole", "chunked"])
    args = parser.parse_args(argv)
    from mmsnap_graph.sim import simulate_recording

    t0 = time.perf_counter()
    base = simulate_recording(_network(), "random",
                              SimulationOptions(physics=None, frame_period_s=FRAME_PERIOD_S, known_poses=True),
                              levels=("centroids",), n_frames=BASE_FRAMES, seed=0)
    print(f"10 nodes, 1 target, centroids, {FRAME_PERIOD_S * 1e3:.0f} ms frames; simulated "
          f"{BASE_FRAMES} frames in {time.perf_counter() - t0:.1f} s; window {args.window} frames")
    with tempfile.TemporaryDirectory() as tmp:
        imports = run_child(Path(tmp) / "none", "import", args.window, args.tracemalloc)
        print(f"imports only: peak RSS {imports['rss_mb']:.0f} MB")
        for hours in args.hours:
            n = int(round(hours * 3600 / FRAME_PERIOD_S))
            path = Path(tmp) / f"rec_{n}.h5"
            make_recording(path, n, base)
            size = path.stat().st_size / 2**20
            res = {m: run_child(path, m, args.window, args.tracemalloc)
                   for m in args.paths}
            if set(res) != {"whole", "chunked"}:
                for m, r in res.items():
                    print(f"{hours:g} h = {n} frames ({size:.0f} MB file, {r['rows']} fused "
                          f"rows): {m} peak RSS {r['rss_mb']:.0f} MB ({r['wall_s']:.1f} s)")
                continue
            w, c = res["whole"], res["chunked"]
            py = (f"; Python peak whole {w['py_mb']:.0f} MB, chunked {c['py_mb']:.0f} MB"
                  if args.tracemalloc else "")
            print(f"{hours:g} h = {n} frames ({size:.0f} MB file, {c['rows']} fused rows): peak "
                  f"RSS whole {w['rss_mb']:.0f} MB ({w['wall_s']:.1f} s), chunked "
                  f"{c['rss_mb']:.0f} MB ({c['wall_s']:.1f} s); whole / chunked "
                  f"{w['rss_mb'] / c['rss_mb']:.2f}x{py}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
