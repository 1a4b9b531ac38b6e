"""One benchmark of ``benchmarks/`` run in two checkouts of the project, in
the same sitting, and the ratio of their CPU times.

    python benchmarks/compare.py OLD_CHECKOUT [--rounds 2] [--python-old PY] \\
        [--python-new PY] [--metric NAME=REGEX ...] -- bench_oneshot.py --frames 500

The benchmark script (a file name under ``benchmarks/``, and its arguments
after ``--``) is run in the old checkout and in this one in ABBA order
(old, new, new, old; ``--rounds`` times), each run a fresh process started
from its checkout's ``benchmarks/`` folder with that checkout's Python
(default ``CHECKOUT/.venv/bin/python``, else this interpreter). For each run
the CPU time of the process and everything it waited for (user + system,
``resource.getrusage(RUSAGE_CHILDREN)``: insensitive to other processes'
load, unlike the wall clock) is measured, and each ``--metric`` is read from
its output: ``NAME=REGEX``, the first group of the regular expression's last
match, a number (for example the CPU median a benchmark prints itself). The
medians of each checkout's runs and the ratio new / old are printed (above 1:
this checkout is slower), with the exact command.

Known metrics of this folder's benchmarks (``--metric NAME`` alone):
see :data:`METRICS`.
"""

from __future__ import annotations

import argparse
import os
import re
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent

#: Metrics the benchmarks of this folder print (old and new wordings alike).
METRICS = {
    # bench_oneshot.py: the CPU median of one GTSAM solve (ms), and scipy's.
    "gtsam_ms": r"CPU time of this process.*?: \S+(?: \(gtsam\))? median ([0-9.]+) ms",
    "scipy_ms": r"CPU time of this process.*scipy median ([0-9.]+) ms",
    # bench_stream.py: the stream's CPU median per frame (ms) of each solver (last target count).
    "stream_scalar_ms": r"solver scalar: stream per frame .*?CPU median ([0-9.]+) ms",
    "stream_gtsam_ms": r"solver gtsam: stream per frame .*?CPU median ([0-9.]+) ms",
    # bench_calibration_scale.py: the calibration's wall time (s) of the last size.
    "calibrate_s": r"nodes x +(?:\d+) frames: +([0-9.]+) s",
    # bench_batch.py: CPU seconds of the batch, of the GTSAM and scipy subsets.
    "batch_cpu_s": r"^batch.*? \(([0-9.]+) s CPU\)",
    "gtsam_cpu_s": r"^GTSAM.*? \(([0-9.]+) s CPU\)",
    "scipy_cpu_s": r"^scipy.*? \(([0-9.]+) s CPU\)",
    # bench_scaleout.py: CPU seconds in the workers (first worker count).
    "workers_cpu_s": r"in workers +[0-9.]+ s wall / +([0-9.]+) s CPU",
    # bench_point_table.py: the reader's best time (s) at the last size.
    "mmsnap_s": r"mmsnap +best +([0-9.]+) s",
    "loadtxt_s": r"loadtxt +best +([0-9.]+) s",
    # bench_fuse_memory.py: peak RSS (MB) and CPU (s) of the last path's child.
    "rss_mb": r"peak RSS ([0-9.]+) MB",
    "child_cpu_s": r"([0-9.]+) s CPU\)",
}


def checkout_python(folder: Path, given: str | None) -> str:
    if given:
        return given
    venv = folder / ".venv" / "bin" / "python"
    return str(venv) if venv.exists() else sys.executable


def run(python: str, folder: Path, argv: list[str]) -> tuple[float, float, str]:
    """One run: (CPU s of the process tree, wall s, stdout)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    out = subprocess.run([python, *argv], cwd=folder / "benchmarks", capture_output=True,
                         text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if out.returncode != 0:
        sys.stderr.write(out.stdout + out.stderr)
        raise SystemExit(f"{' '.join(argv)} failed in {folder} (exit {out.returncode})")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return cpu, wall, out.stdout


def read_metric(regex: str, text: str) -> float | None:
    found = re.findall(regex, text, flags=re.M)
    return float(found[-1]) if found else None


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if "--" not in argv:
        raise SystemExit("usage: compare.py OLD_CHECKOUT [options] -- BENCHMARK.py [ARGS]")
    cut = argv.index("--")
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("old", type=Path, help="the other checkout (its benchmarks/ is run)")
    ap.add_argument("--rounds", type=int, default=1, help="ABBA rounds (4 runs each)")
    ap.add_argument("--python-old")
    ap.add_argument("--python-new")
    ap.add_argument("--metric", action="append", default=[],
                    help="NAME=REGEX, or a NAME of METRICS")
    ap.add_argument("--show", action="store_true", help="print each run's output")
    args = ap.parse_args(argv[:cut])
    bench = argv[cut + 1:]
    if not bench:
        raise SystemExit("no benchmark after --")
    new = HERE.parent
    trees = {"old": (args.old.resolve(), checkout_python(args.old.resolve(), args.python_old)),
             "new": (new, checkout_python(new, args.python_new))}
    metrics = {}
    for m in args.metric:
        name, _, regex = m.partition("=")
        metrics[name] = regex or METRICS[name]
    results = {"old": [], "new": []}
    for _ in range(args.rounds):
        for which in ("old", "new", "new", "old"):
            folder, python = trees[which]
            cpu, wall, text = run(python, folder, bench)
            values = {k: read_metric(r, text) for k, r in metrics.items()}
            results[which].append((cpu, wall, values))
            shown = " ".join(f"{k}={v}" for k, v in values.items())
            print(f"  {which}: CPU {cpu:8.2f} s, wall {wall:8.2f} s {shown}", flush=True)
            if args.show:
                print(text)
    print(f"command: {' '.join(bench)} (in each checkout's benchmarks/; old {trees['old'][0]}, "
          f"new {trees['new'][0]}; {args.rounds} ABBA round(s); load {os.getloadavg()[0]:.1f})")

    def med(which, key):
        vals = [r[0] if key == "cpu" else r[2][key] for r in results[which]]
        vals = [v for v in vals if v is not None]
        return statistics.median(vals) if vals else float("nan")

    for key in ["cpu", *metrics]:
        old, new_ = med("old", key), med("new", key)
        label = "process CPU s" if key == "cpu" else key
        print(f"{label:>16}: old {old:10.4f}  new {new_:10.4f}  new/old {new_ / old:.3f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
