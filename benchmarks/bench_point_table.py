"""Speed and memory of the CSV point-table reader
(:func:`mmsnap_graph.io.read_point_tables`) against plain readers of the
same file, in the same run.

A TI-style log of two radars is written once per size (``node, frame,
time_s, x, y, z, doppler, snr``; seeded; about 16 points a frame, the
nodes interleaved as a logger writes them). On each file, each reader is
timed ``--repeat`` times (the best and the median are printed) and run once
more under :mod:`tracemalloc` for its peak of Python allocations:

- ``mmsnap``: ``read_point_tables(path)``, every check included (columns,
  finite values, ranges, frame numbers, one cloud per node);
- ``loadtxt``: ``numpy.loadtxt`` of the seven numeric columns plus the node
  column as strings (no checks);
- ``csv``: the standard library's ``csv.reader`` and ``float`` on every
  numeric cell (no checks);
- ``pandas``: ``pandas.read_csv(path)`` (no checks), when pandas is installed.

Printed per size: rows/s of each reader, the ratio of each baseline's time to
the reader's (above 1: the reader is faster), and the peak memory in MB and
bytes per row. The last lines give the growth from the smallest to the
largest size (time per row; 1.0 = linear).

Usage::

    python benchmarks/bench_point_table.py [--rows 50000 200000 500000] [--repeat 3]
                                           [--no-memory]
"""

from __future__ import annotations

import argparse
import csv
import statistics
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np

from mmsnap_graph.io import read_point_tables

POINTS_PER_FRAME = 16


def write_table(path: Path, rows: int, seed: int = 0) -> None:
    """A two-radar point log of ``rows`` rows at ``path`` (20 frames/s)."""
    rng = np.random.default_rng(seed)
    frame = np.sort(rng.integers(0, max(rows // POINTS_PER_FRAME, 1), rows))
    node = np.where(rng.random(rows) < 0.5, "S1", "S2")
    xyz = rng.normal(0.0, 1.5, (rows, 3)) + [0.0, 3.0, 1.0]
    doppler = rng.normal(0.0, 0.8, rows)
    snr = 10.0 + 20.0 * rng.random(rows)
    time_s = 1.7e9 + 0.05 * frame
    with open(path, "w", encoding="utf-8") as f:
        f.write("node,frame,time_s,x,y,z,doppler,snr\n")
        f.writelines(f"{node[i]},{frame[i]},{time_s[i]:.6f},{xyz[i, 0]:.6f},{xyz[i, 1]:.6f},"
                     f"{xyz[i, 2]:.6f},{doppler[i]:.6f},{snr[i]:.6f}\n" for i in range(rows))


def read_mmsnap(path: Path) -> int:
    return sum(c.x_m.size for c in read_point_tables(path).values())


def read_loadtxt(path: Path) -> int:
    numbers = np.loadtxt(path, delimiter=",", skiprows=1, usecols=range(1, 8), ndmin=2)
    nodes = np.loadtxt(path, delimiter=",", skiprows=1, usecols=[0], dtype=str)
    assert nodes.shape[0] == numbers.shape[0]
    return numbers.shape[0]


def read_csv_module(path: Path) -> int:
    with open(path, newline="", encoding="utf-8") as f:
        rows = csv.reader(f)
        next(rows)
        table = [(r[0], *map(float, r[1:])) for r in rows]
    return len(table)


def read_pandas(path: Path) -> int:
    import pandas

    return len(pandas.read_csv(path))


def readers() -> dict:
    out = {"mmsnap": read_mmsnap, "loadtxt": read_loadtxt, "csv": read_csv_module}
    try:
        import pandas  # noqa: F401
        out["pandas"] = read_pandas
    except ImportError:
        print("pandas is not installed: its column is left out")
    return out


def timed(read, path: Path, rows: int, repeat: int) -> list[float]:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        n = read(path)
        times.append(time.perf_counter() - t0)
        if n != rows:
            raise SystemExit(f"{read.__name__} read {n} rows of {rows}")
    return times


def peak_mb(read, path: Path) -> float:
    tracemalloc.start()
    try:
        read(path)
        return tracemalloc.get_traced_memory()[1] / 1e6
    finally:
        tracemalloc.stop()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rows", type=int, nargs="+", default=[50_000, 200_000, 500_000])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--no-memory", action="store_true", help="skip the tracemalloc runs")
    args = parser.parse_args()
    funcs = readers()
    per_row = {}
    with tempfile.TemporaryDirectory() as tmp:
        for rows in args.rows:
            path = Path(tmp) / f"points_{rows}.csv"
            write_table(path, rows)
            size_mb = path.stat().st_size / 1e6
            print(f"\n{rows:,} rows ({size_mb:.1f} MB):")
            best = {}
            for name, read in funcs.items():
                t = timed(read, path, rows, args.repeat)
                best[name] = min(t)
                mem = "" if args.no_memory else (
                    f", peak {peak_mb(read, path):.0f} MB "
                    f"({peak_mb(read, path) * 1e6 / rows:.0f} B/row)")
                print(f"  {name:8s} best {min(t):6.3f} s, median {statistics.median(t):6.3f} s: "
                      f"{rows / min(t):>10,.0f} rows/s{mem}")
            ratios = ", ".join(f"{name} {best[name] / best['mmsnap']:.2f}x"
                               for name in funcs if name != "mmsnap")
            print(f"  baseline time / mmsnap time (above 1: mmsnap faster): {ratios}")
            per_row[rows] = {name: best[name] / rows for name in funcs}
    if len(per_row) > 1:
        lo, hi = min(per_row), max(per_row)
        growth = ", ".join(f"{name} {per_row[hi][name] / per_row[lo][name]:.2f}"
                           for name in funcs)
        print(f"\ntime per row at {hi:,} rows / at {lo:,} rows (1.0 = linear): {growth}")


if __name__ == "__main__":
    main()
