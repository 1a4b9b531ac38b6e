"""Seeded Monte Carlo over random radar layouts, through the ``mmsnap`` CLI.

Each run draws a network of 2-5 radars whose fields of view overlap
(:func:`mmsnap_graph.sim.networks.random_network`), then runs what a user
runs: ``mmsnap simulate --model real`` (20 fps or 150 ms frames, one or two
walkers), ``process``, ``calibrate``, ``fuse`` and ``evaluate --json``, and
prints one line per run: the fused NEES (dof 4: x, y, vx, vy) and the
position RMSE of the successful rows, with the share of rows that succeeded
and what the self-check of ``fuse`` said (``consistency``).

    python tools/random_layouts.py --runs 16 --seed 0          # the note's table
    python tools/random_layouts.py --runs 4 --frames 300 --json-out runs.json

``--paper`` adds the paper's layouts A, B and C at both frame periods.
Each run's command lines are printed with ``--show-commands``.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

#: Frame periods of the runs: TI's default 20 fps and the paper's 150 ms.
FRAME_PERIODS_S = (0.05, 0.15)


@dataclass(frozen=True)
class Run:
    """One Monte Carlo run: a layout (None: a paper configuration), its
    frame period, walkers and simulation seed."""

    name: str
    nodes: tuple | None          # ((name, x_m, y_m, phi_rad), ...)
    configuration: str | None
    frame_period_s: float
    targets: int
    seed: int
    frames: int

    def simulate_args(self) -> list[str]:
        if self.nodes is None:
            where = ["-c", self.configuration]
        else:
            where = [a for n, x, y, phi in self.nodes
                     for a in ("--node", f"{n}={x:.3f},{y:.3f},{math.degrees(phi):.2f}")]
        return [*where, "-t", "random", "--model", "real", "-n", str(self.frames),
                "--frame-period", str(self.frame_period_s), "--targets", str(self.targets),
                "-s", str(self.seed), "-l", "centroids,point_cloud"]


def draw_runs(n_runs: int, seed: int, frames: int) -> list[Run]:
    """``n_runs`` runs cycling through 2-5 radars, both frame periods and
    one or two walkers, each with its own layout drawn from ``seed``."""
    from mmsnap_graph.sim.networks import random_network

    rng = np.random.default_rng(seed)
    runs = []
    for i in range(n_runs):
        n_nodes = 2 + i % 4
        period = FRAME_PERIODS_S[(i // 4) % 2]
        targets = 1 + (i // 8) % 2
        poses = random_network(n_nodes, rng)
        nodes = tuple((k, *map(float, v)) for k, v in poses.items())
        runs.append(Run(name=f"R{i:02d}", nodes=nodes, configuration=None,
                        frame_period_s=period, targets=targets,
                        seed=int(rng.integers(0, 2**31 - 1)), frames=frames))
    return runs


def paper_runs(seed: int, frames: int) -> list[Run]:
    return [Run(name=f"{c}@{int(p * 1000)}ms", nodes=None, configuration=c, frame_period_s=p,
                targets=1, seed=seed, frames=frames)
            for c in "ABC" for p in FRAME_PERIODS_S]


def commands(run: Run, path: Path) -> list[list[str]]:
    """The CLI commands of one run, recording ``path``."""
    rec = str(path)
    return [["simulate", *run.simulate_args(), "-o", rec, "--overwrite", "--no-progress"],
            ["process", rec, "--no-progress"],
            ["calibrate", rec, "--no-progress"],
            ["fuse", rec, "--no-progress", "--max-flagged", "1", "--json"],
            ["evaluate", rec, "--json"]]


def _mmsnap(cmd: list[str], show: bool) -> subprocess.CompletedProcess:
    if show:
        print("  mmsnap " + " ".join(cmd), file=sys.stderr)
    return subprocess.run([sys.executable, "-m", "mmsnap_graph", *cmd], capture_output=True,
                          text=True)


def scaled_sigmas(path: Path, scale: float) -> list[str]:
    """``--sigmas`` of ``scale`` times the nodes' mean sigmas in ``/noise``."""
    from mmsnap_graph.io.noise import read_noise

    est = read_noise(path)
    sig = np.mean([np.asarray(n.sigmas, float) for n in est.per_node.values()], axis=0)
    return [f"{v:.5g}" for v in scale * sig]


def scaled_run(path: Path, scale: float, show: bool) -> dict:
    """The run fused again with every sigma scaled by ``scale`` (a copy)."""
    copy = path.with_suffix(f".x{scale:g}.h5")
    p = _mmsnap(["fuse", str(path), "--sigmas", *scaled_sigmas(path, scale), "-o", str(copy),
                 "--overwrite", "--no-progress", "--max-flagged", "1", "--json"], show)
    fu = json.loads(_mmsnap(["evaluate", str(copy), "--json"], show).stdout)["fused"]
    copy.unlink()
    return {"scale": scale, "nees": fu["nees"]["mean"], "position_rmse_m": fu["position_rmse_m"],
            "consistency": json.loads(p.stdout)["consistency"]}


def run_one(run: Run, folder: Path, *, show: bool = False, scales=()) -> dict:
    """Run the CLI on ``run`` in ``folder``; the run's figures (and those of
    the run fused with its sigmas times each of ``scales``)."""
    path = folder / f"{run.name.replace('@', '_')}.h5"
    outputs = []
    for cmd in commands(run, path):
        p = _mmsnap(cmd, show)
        if p.returncode != 0 and cmd[0] != "fuse":
            raise RuntimeError(f"mmsnap {cmd[0]} failed on {run.name}: {p.stderr[-2000:]}")
        outputs.append(p)
    fuse_json = json.loads(outputs[3].stdout)
    ev = json.loads(outputs[4].stdout)
    fu = ev["fused"]
    return {"run": run.name, "n_nodes": len(run.nodes) if run.nodes else 2,
            "frame_period_s": run.frame_period_s, "targets": run.targets, "seed": run.seed,
            "layout": [list(n) for n in run.nodes] if run.nodes else run.configuration,
            "nees": fu["nees"]["mean"], "nees_interval_95": fu["nees"]["interval_95"],
            "position_rmse_m": fu["position_rmse_m"], "n_rows": fu["n_rows"],
            "n_success": fu["n_success"], "n_truth_rows": ev["n_truth_rows"],
            "consistency": fuse_json.get("consistency"),
            "scaled": [scaled_run(path, s, show) for s in scales]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=16, help="random layouts (default 16)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the layouts (default 0)")
    ap.add_argument("--frames", type=int, default=600, help="frames per run (default 600)")
    ap.add_argument("--paper", action="store_true", help="add the paper's A, B, C")
    ap.add_argument("--only", default=None, help="comma-separated run names to run")
    ap.add_argument("--scales", default="",
                    help="also fuse each run with its sigmas times these (e.g. 0.3,3): the "
                         "self-check must fire there")
    ap.add_argument("--show-commands", action="store_true")
    ap.add_argument("--json-out", default=None, help="write every run's figures here")
    args = ap.parse_args(argv)
    runs = draw_runs(args.runs, args.seed, args.frames)
    if args.paper:
        runs += paper_runs(args.seed, args.frames)
    if args.only:
        keep = set(args.only.split(","))
        runs = [r for r in runs if r.name in keep]
    scales = [float(v) for v in args.scales.split(",") if v.strip()]
    rows = []
    print(f"{'run':10s} {'nodes':>5s} {'period':>6s} {'walkers':>7s} {'NEES':>6s} "
          f"{'RMSE m':>7s} {'ok/truth':>9s}  self-check")
    with tempfile.TemporaryDirectory(prefix="random_layouts.") as tmp:
        for run in runs:
            r = run_one(run, Path(tmp), show=args.show_commands, scales=scales)
            rows.append(r)
            c = r["consistency"] or {}
            print(f"{r['run']:10s} {r['n_nodes']:5d} {r['frame_period_s']:6.2f} "
                  f"{r['targets']:7d} {r['nees']:6.2f} {r['position_rmse_m']:7.3f} "
                  f"{r['n_success'] / max(r['n_truth_rows'], 1):9.2f}  "
                  f"{c.get('verdict', '-')} (innovation {c.get('innovation_nis') or 0:.2f}, "
                  f"residual {c.get('residual_ratio') or 0:.2f})"
                  + "".join(f"; x{s['scale']:g}: NEES {s['nees']:.2f} "
                            f"{s['consistency']['verdict']} "
                            f"({s['consistency']['innovation_nis'] or 0:.2f}, "
                            f"{s['consistency']['residual_ratio'] or 0:.2f})"
                            for s in r["scaled"]), flush=True)
    if args.json_out:
        Path(args.json_out).write_text(json.dumps(rows, indent=1))
    bad = [r["run"] for r in rows if not (4 / 1.5 <= r["nees"] <= 4 * 1.5)
           or r["position_rmse_m"] > 0.2]
    print(f"{len(rows) - len(bad)}/{len(rows)} runs with NEES in [2.67, 6] and RMSE <= 0.2 m"
          + (f"; not: {', '.join(bad)}" if bad else ""))
    fired = sum(r["consistency"]["consistent"] is False for r in rows)
    print(f"self-check fired on {fired}/{len(rows)} runs as fused")
    for s in scales:
        got = [x for r in rows for x in r["scaled"] if x["scale"] == s]
        n = sum(x["consistency"]["consistent"] is False for x in got)
        print(f"self-check fired on {n}/{len(got)} runs with the sigmas x{s:g}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
