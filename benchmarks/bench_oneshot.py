"""Per-frame latency of one-shot fusion: GTSAM (``solve``, ``solver="gtsam"``) against scipy.

Two nodes in configuration B, noisy measurements with the paper's sigmas
(seeded). Each method solves the MAP problem of paper eq. (18) and returns a
4x4 covariance:

- GTSAM: a ``FrameProblem`` of the frame (validation) and ``solve`` with
  ``solver="gtsam"`` (the initial values of docs/CONVENTIONS.md, GTSAM Levenberg-Marquardt
  and ``gtsam.Marginals`` (the whole public call);
- scipy: ``scipy.optimize.least_squares`` (method "lm", analytic Jacobian from
  :func:`factors.models.measurement_model`, same initial values and tight
  tolerances) plus the covariance ``(J^T J)^{-1}`` from its final Jacobian.

Both run on the same frames in the same process; the script prints both
medians, the ratio and the largest state disagreement.

Usage::

    python benchmarks/bench_oneshot.py [--frames 2000] [--seed 0]
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

from frames import POSES, scipy_fuse, simulate
from mmsnap_graph.data.noise import GaussianPrior, MeasurementNoise
from mmsnap_graph.fusion.options import FusionOptions
from mmsnap_graph.fusion.frame_problem import FrameProblem
from mmsnap_graph.fusion.solve import solve

GTSAM = FusionOptions(solver="gtsam")

POSES_B = POSES["B"]


def time_per_frame(fn, frames) -> tuple[np.ndarray, np.ndarray]:
    """Wall-clock and CPU (this process) seconds per call."""
    wall = np.empty(len(frames))
    cpu = np.empty(len(frames))
    for k, args in enumerate(frames):
        c0 = time.process_time()
        t0 = time.perf_counter()
        fn(*args)
        wall[k] = time.perf_counter() - t0
        cpu[k] = time.process_time() - c0
    return wall, cpu


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=2000)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    noise = MeasurementNoise()
    prior = GaussianPrior()
    _, z = simulate("B", args.frames, args.seed, half_width_m=1.0)

    def gtsam_call(zk):
        return solve(FrameProblem(poses=POSES_B, measurements=zk, noise=noise, prior=prior), GTSAM)

    def scipy_call(zk):
        return scipy_fuse(POSES_B, zk, noise, prior)

    frames = [(zk,) for zk in z]
    # Warm-up (imports, caches), then interleave the two methods in blocks so
    # that machine load affects both alike.
    for zk in z[:50]:
        gtsam_call(zk)
        scipy_call(zk)
    t_gtsam, t_scipy, c_gtsam, c_scipy = [], [], [], []
    block = 100
    for start in range(0, len(frames), block):
        part = frames[start : start + block]
        wall, cpu = time_per_frame(gtsam_call, part)
        t_gtsam.append(wall)
        c_gtsam.append(cpu)
        wall, cpu = time_per_frame(scipy_call, part)
        t_scipy.append(wall)
        c_scipy.append(cpu)
    t_gtsam, t_scipy = np.concatenate(t_gtsam), np.concatenate(t_scipy)
    c_gtsam, c_scipy = np.concatenate(c_gtsam), np.concatenate(c_scipy)

    diff_state = 0.0
    diff_cov = 0.0
    n_fail = 0
    iters = []
    for zk in z[: min(300, len(z))]:
        res = gtsam_call(zk)
        x_s, c_s = scipy_call(zk)
        n_fail += not res.success[0]
        iters.append(int(res.iterations[0]))
        diff_state = max(diff_state, float(np.max(np.abs(res.state[0] - x_s))))
        diff_cov = max(diff_cov, float(np.max(np.abs(res.covariance[0] - c_s) / np.sqrt(np.outer(np.diag(c_s), np.diag(c_s))))))

    # The paper's grid covariance (an option; 21^4 grid points per frame).
    t_grid = []
    for zk in z[:5]:
        t0 = time.perf_counter()
        solve(FrameProblem(poses=POSES_B, measurements=zk, noise=noise, prior=prior),
              FusionOptions(solver="gtsam", covariance="grid"))
        t_grid.append(time.perf_counter() - t0)

    med_g = np.median(t_gtsam) * 1e3
    med_s = np.median(t_scipy) * 1e3
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"frames: {args.frames} (configuration B, two nodes, seed {args.seed}); "
          f"1-min load average {load:.2f} on {os.cpu_count()} CPUs")
    print(f"solve, gtsam (LM + Marginals)    : median {med_g:.4f} ms, p90 {np.percentile(t_gtsam, 90) * 1e3:.4f} ms")
    print(f"scipy least_squares + J^T J cov  : median {med_s:.4f} ms, p90 {np.percentile(t_scipy, 90) * 1e3:.4f} ms")
    print(f"speed-up (scipy / GTSAM medians) : {med_s / med_g:.2f}x")
    cpu_g, cpu_s = np.median(c_gtsam) * 1e3, np.median(c_scipy) * 1e3
    print(f"CPU time of this process (insensitive to other processes' load): "
          f"solve (gtsam) median {cpu_g:.4f} ms, scipy median {cpu_s:.4f} ms, ratio {cpu_s / cpu_g:.2f}x")
    print(f"target: median <= 0.15 ms and >= 4x -> {'met' if med_g <= 0.15 and med_s / med_g >= 4 else 'NOT met'}")
    print(f"with covariance='grid' (Laplace + 21^4-point grid): median {np.median(t_grid) * 1e3:.1f} ms per frame (5 frames)")
    print(f"agreement on {len(iters)} frames: max |state diff| {diff_state:.2e}, "
          f"max covariance diff / sigma_i sigma_j {diff_cov:.2e}, failures {n_fail}, "
          f"LM iterations median {np.median(iters):.0f} max {max(iters)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
