"""Speed of the per-node signal chain on two cube shapes: Table I (512 x 60
x 12, the paper's) and a TI-style sub-frame of 32 loops (512 x 32 x 12, as
the AWR1843 capture of issue 14).

Prints frames per second per stage and for the whole chain (cube ->
centroids, then centroids -> tracks), against a baseline measured in the
same run: numpy's plain 2D FFT (``np.fft.fft2`` over range and Doppler) of
the same cube, without windows, clutter removal or anything else.

Single-threaded by construction (scipy.fft ``workers=1``; set
``OMP_NUM_THREADS=1`` for BLAS). The cubes are a walking person plus static
clutter and thermal noise, synthesized once before timing.

The last lines print, per shape, the chain's time to the point cloud and to
the torso centroids over the bare FFT's, both measured in the same run (best
of the interleaved rounds, each round's ratio beside it, and the ratio of CPU
times): the target is <= 1.0 (issue 14).

Usage: ``python benchmarks/bench_chain.py [--frames 100] [--repeat 3] [--loops 60 32]``
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import dataclasses  # noqa: E402

import numpy as np  # noqa: E402

from mmsnap_graph.radar.cfar import os_cfar_2d
from mmsnap_graph.radar.chain import (
    ChainConfig,
    _frame_status,
    _range_slice,
    point_cloud_of_cube,
    process_cubes,
)
from mmsnap_graph.radar.cluster import torso_centroids
from mmsnap_graph.data.radar_config import TABLE_I
from mmsnap_graph.radar.spectrum import range_doppler
from mmsnap_graph.sim.body import body_scatterers
from mmsnap_graph.sim.cube import scatterer_amplitude, synthesize_cubes
from mmsnap_graph.tracking.ekf import EkfConfig, track_centroids


def make_cubes(n: int, seed: int = 0, config=TABLE_I) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = np.arange(n) * config.frame_period_s
    # Walking back and forth between 2 and 9 m, slightly off broadside.
    y = 5.5 + 3.5 * np.sin(2 * np.pi * t / 12.0)
    vy = 3.5 * 2 * np.pi / 12.0 * np.cos(2 * np.pi * t / 12.0)
    states = np.stack([0.8 + 0 * t, y, 0 * t, vy], axis=1)
    body = body_scatterers(states, config.frame_period_s, rng=rng)
    r = np.hypot(body.positions_m[..., 0], body.positions_m[..., 1])
    amp = scatterer_amplitude(config, body.rcs_m2[None, :], r) * np.exp(
        2j * np.pi * rng.random(r.shape))
    n_cl = 10
    cr = rng.uniform(1, 15, n_cl)
    ct = rng.uniform(-1, 1, n_cl)
    clutter = (np.stack([cr * np.sin(ct), cr * np.cos(ct)], 1),
               scatterer_amplitude(config, rng.uniform(0.5, 5, n_cl), cr))
    return synthesize_cubes(config, body.positions_m, body.velocities_mps, amp, rng=rng,
                            noise_std=1.0, clutter=clutter)


def bench_shape(config, n: int, repeat: int) -> float:
    """Print the stage table of one cube shape; return chain / bare FFT."""
    chain = ChainConfig()
    cubes = make_cubes(n, config=config)
    print(f"\n{n} cubes {config.cube_shape} complex64; best of {repeat}; "
          f"1 thread; machine shared with other jobs (figures measured under load)")

    def per_frame(fn):
        return lambda: [fn(cubes[i]) for i in range(n)]

    rs = _range_slice(config, chain)
    powers = [range_doppler(cubes[i], config, range_bins=rs)[1] for i in range(n)]
    res = process_cubes(cubes, config, chain)
    ekf = EkfConfig(frame_period_s=config.frame_period_s)
    work = {
        "baseline np.fft.fft2 (no window)":
            per_frame(lambda c: np.fft.fft2(c, axes=(0, 1))),
        "frame check (finite, energy)": per_frame(lambda c: _frame_status(c, chain)),
        "range+Doppler FFT, clutter removal, power":
            per_frame(lambda c: range_doppler(c, config, range_bins=rs)),
        "point cloud (all of the above + CFAR cells + angle)":
            per_frame(lambda c: point_cloud_of_cube(c, config, chain)),
        "reference: whole-map ndimage OS-CFAR only":
            lambda: [os_cfar_2d(p, chain.cfar, config.n_virtual) for p in powers],
        "torso DBSCAN (all frames)":
            lambda: torso_centroids(res.point_cloud, chain.cluster,
                                    doppler_resolution_mps=config.doppler_resolution_mps),
        "cube -> centroids (process_cubes)": lambda: process_cubes(cubes, config, chain),
        "centroids -> EKF tracks": lambda: track_centroids(res.centroids, ekf),
    }
    # Interleaved repeats (every stage once per round, best round kept), so
    # that a burst of load from other jobs hits all stages alike. Wall-clock
    # time is the figure; CPU time (process_time) is printed beside it, it is
    # less sensitive to the other jobs' scheduling.
    rounds = {name: [] for name in work}
    for _ in range(repeat):
        for name, fn in work.items():
            t0, c0 = time.perf_counter(), time.process_time()
            fn()
            rounds[name].append((time.perf_counter() - t0, time.process_time() - c0))
    stages = {name: min(r[0] for r in rs) for name, rs in rounds.items()}
    cpu = {name: min(r[1] for r in rs) for name, rs in rounds.items()}
    base_name = "baseline np.fft.fft2 (no window)"
    base, base_cpu = stages[base_name], cpu[base_name]
    print(f"{'stage':55s} {'ms/frame':>9s} {'frames/s':>9s} {'x baseline':>10s} "
          f"{'cpu ms':>7s} {'cpu x':>6s}")
    for name, t in stages.items():
        print(f"{name:55s} {1e3 * t / n:9.3f} {n / t:9.1f} {t / base:10.2f} "
              f"{1e3 * cpu[name] / n:7.3f} {cpu[name] / base_cpu:6.2f}")
    print(f"points/frame {len(res.point_cloud) / n:.1f}, centroids/frame "
          f"{len(res.centroids) / n:.2f}, flagged frames {int(np.sum(res.status != 0))}")
    out = {}
    for key, name in (("point cloud", "point cloud (all of the above + CFAR cells + angle)"),
                      ("centroids", "cube -> centroids (process_cubes)")):
        per_round = [r[0] / b[0] for r, b in zip(rounds[name], rounds[base_name])]
        out[key] = (stages[name] / base, cpu[name] / base_cpu, per_round)
    return out


def _load() -> str:
    return " ".join(f"{v:.2f}" for v in os.getloadavg())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--loops", type=int, nargs="+", default=[60, 32],
                    help="chirp loops per frame of each cube shape (512 x loops x 12)")
    args = ap.parse_args()
    load0 = _load()
    ratios = {}
    for loops in args.loops:
        config = dataclasses.replace(TABLE_I, n_loops=int(loops))
        ratios[config.cube_shape] = bench_shape(config, args.frames, args.repeat)
    print(f"\nload average before / after: {load0} / {_load()}; best of {args.repeat} "
          f"interleaved rounds of {args.frames} frames")
    for shape, ratio in ratios.items():
        for key, (wall, cpu_ratio, per_round) in ratio.items():
            rounds = " ".join(f"{r:.2f}" for r in per_round)
            print(f"chain to the {key} / bare np.fft.fft2 on {shape}: {wall:.2f} "
                  f"(target <= 1.0; per round {rounds}; CPU time {cpu_ratio:.2f})")


if __name__ == "__main__":
    main()
