"""Throughput of batch one-shot fusion against the per-frame paths.

Two nodes (configuration B by default), MAP with the paper's prior and noise,
noisy measurements drawn around the common area (seeded). Every method returns
the state and its 4x4 Laplace covariance:

- batch: :func:`mmsnap_graph.fusion.solve.solve` with ``solver="vectorized"`` on all frames at once
  (the problem module's vectorized initial values, LM vectorized over frames, covariance
  by batched Cholesky); the whole public call, validation included;
- GTSAM: ``solve`` with ``solver="gtsam"``, one frame at a time;
- scipy: ``scipy.optimize.least_squares`` (method "lm", analytic Jacobian from
  :func:`factors.models.measurement_model`, the same initial values, tight
  tolerances) and ``(J^T J)^{-1}``, one frame at a time.

The per-frame paths run on a subset (``--per-frame``) and are interleaved in
blocks with each other so that machine load hits them alike; the batch runs
``--repeat`` times and the best is kept. Times are wall-clock; the CPU time of
the process is printed too (on a shared machine it is the fairer figure).
The script also checks the batch result against GTSAM on the subset.

Usage::

    python benchmarks/bench_batch.py [--frames 200000] [--per-frame 2000]
                                     [--configuration B] [--seed 0] [--repeat 3]
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

from frames import POSES, scipy_fuse, simulate
from mmsnap_graph.data.noise import GaussianPrior, MeasurementNoise
from mmsnap_graph.fusion.frame_problem import FrameProblem
from mmsnap_graph.fusion.options import FusionOptions
from mmsnap_graph.fusion.solve import solve


def fuse_batch(poses, z, noise, prior):
    """All frames at once: the problem (validated) and the vectorized solve."""
    return solve(FrameProblem(poses=poses, measurements=z, noise=noise, prior=prior),
                 FusionOptions(solver="vectorized"))


def fuse_frame(poses, z, noise, prior):
    """One frame: its problem (validated) and the GTSAM solve."""
    return solve(FrameProblem(poses=poses, measurements=z, noise=noise, prior=prior), GTSAM)


GTSAM = FusionOptions(solver="gtsam")

def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=200_000)
    parser.add_argument("--per-frame", type=int, default=2000)
    parser.add_argument("--configuration", choices=sorted(POSES), default="B")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args(argv)
    poses = POSES[args.configuration]
    noise, prior = MeasurementNoise(), GaussianPrior()
    _, z = simulate(args.configuration, args.frames, args.seed)

    fuse_batch(poses, z[:1000], noise, prior)  # warm-up
    best_wall = best_cpu = np.inf
    for _ in range(args.repeat):
        w0, c0 = time.perf_counter(), time.process_time()
        res = fuse_batch(poses, z, noise, prior)
        best_wall = min(best_wall, time.perf_counter() - w0)
        best_cpu = min(best_cpu, time.process_time() - c0)

    sub = z[: args.per_frame]
    for zk in sub[:50]:  # warm-up
        fuse_frame(poses, zk, noise, prior)
        scipy_fuse(poses, zk, noise, prior)
    t_g = t_s = 0.0
    c_g = c_s = 0.0
    ref = []
    for start in range(0, len(sub), 100):
        part = sub[start:start + 100]
        w0, c0 = time.perf_counter(), time.process_time()
        out = [fuse_frame(poses, zk, noise, prior) for zk in part]
        t_g += time.perf_counter() - w0
        c_g += time.process_time() - c0
        ref.extend(out)
        w0, c0 = time.perf_counter(), time.process_time()
        for zk in part:
            scipy_fuse(poses, zk, noise, prior)
        t_s += time.perf_counter() - w0
        c_s += time.process_time() - c0

    n_sub = len(sub)
    ok_ref = np.array([r.success[0] for r in ref])
    mismatch = int(np.count_nonzero(ok_ref != res.success[:n_sub]))
    both = ok_ref & res.success[:n_sub]
    st = np.array([r.state[0] for r in ref])[both]
    cv = np.array([r.covariance[0] for r in ref])[both]
    d_state = float(np.max(np.abs(st - res.state[:n_sub][both]))) if both.any() else float("nan")
    d_cov = float(np.max(np.abs(cv - res.covariance[:n_sub][both]))) if both.any() else float("nan")

    fps_b, fps_bc = args.frames / best_wall, args.frames / best_cpu
    fps_g, fps_s = n_sub / t_g, n_sub / t_s
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"configuration {args.configuration}, two nodes, MAP, seed {args.seed}; "
          f"1-min load average {load:.2f} on {os.cpu_count()} CPUs (shared machine: figures under load)")
    print(f"batch (vectorized)    : {args.frames} frames in {best_wall:.3f} s wall "
          f"({best_cpu:.3f} s CPU): {fps_b:,.0f} frames/s wall, {fps_bc:,.0f} frames/s CPU, "
          f"{1e6 / fps_b:.2f} us/frame; success {res.success.mean():.4f}, "
          f"iterations median {np.median(res.iterations):.0f} max {res.iterations.max()}")
    print(f"GTSAM, one frame      : {n_sub} frames in {t_g:.3f} s wall ({c_g:.3f} s CPU): "
          f"{fps_g:,.0f} frames/s, {1e6 / fps_g:.1f} us/frame")
    print(f"scipy least_squares   : {n_sub} frames in {t_s:.3f} s wall ({c_s:.3f} s CPU): "
          f"{fps_s:,.0f} frames/s, {1e6 / fps_s:.1f} us/frame")
    print(f"ratios (wall)         : batch / GTSAM = {fps_b / fps_g:.0f}x, batch / scipy = {fps_b / fps_s:.0f}x, "
          f"GTSAM / scipy = {fps_g / fps_s:.1f}x")
    print(f"target >= 200,000 frames/s on one core: {'met' if fps_b >= 200_000 else 'NOT met'} (wall), "
          f"{'met' if fps_bc >= 200_000 else 'NOT met'} (CPU)")
    print(f"batch vs GTSAM on {n_sub} frames: flag mismatches {mismatch}, max |state diff| {d_state:.2e}, "
          f"max |covariance diff| {d_cov:.2e}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
