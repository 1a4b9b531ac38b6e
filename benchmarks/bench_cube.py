"""Speed of raw-ADC cube synthesis (:mod:`mmsnap_graph.sim.cube`).

The target workload: a 600-frame two-node recording, 1200 Table I cubes
(512 x 60 x 12 complex64) of about 15 scatterers each, in under a minute.
Cubes are synthesized in chunks into one reused buffer (the whole recording
would be 3.5 GB), so the figure is synthesis time, not memory traffic of a
giant array. Baseline in the same run: drawing the same cubes' complex
Gaussian noise alone (float32 ``standard_normal``), the floor of any
synthesizer with thermal noise.

Usage: ``python benchmarks/bench_cube.py [--frames 600] [--nodes 2] [--scatterers 15]``
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from mmsnap_graph.data.radar_config import TABLE_I
from mmsnap_graph.sim.cube import scatterer_amplitude, synthesize_cubes


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=600)
    ap.add_argument("--nodes", type=int, default=2)
    ap.add_argument("--scatterers", type=int, default=15)
    ap.add_argument("--chunk", type=int, default=8)
    args = ap.parse_args()
    config = TABLE_I
    rng = np.random.default_rng(0)
    m, chunk = args.scatterers, args.chunk
    total = args.frames * args.nodes
    buf = np.empty((chunk, *config.cube_shape), np.complex64)
    clutter = (rng.uniform([-5, 1], [5, 15], (10, 2)), np.full(10, 0.05))

    t0 = time.perf_counter()
    done = 0
    while done < total:
        k = min(chunk, total - done)
        pos = rng.uniform([-3, 1], [3, 10], (k, m, 2))
        vel = rng.normal(0, 1, (k, m, 2))
        amp = scatterer_amplitude(config, 0.05, np.hypot(pos[..., 0], pos[..., 1]))
        synthesize_cubes(config, pos, vel, amp, rng=rng, noise_std=1.0, clutter=clutter,
                         out=buf[:k])
        done += k
    t_synth = time.perf_counter() - t0

    t0 = time.perf_counter()
    noise_shape = (*config.cube_shape[:2], 2 * config.cube_shape[2])
    for _ in range(total):
        rng.standard_normal(noise_shape, dtype=np.float32)
    t_noise = time.perf_counter() - t0

    print(f"{total} cubes {config.cube_shape} ({args.frames} frames x {args.nodes} nodes), "
          f"{m} scatterers + 10 clutter; 1 thread; machine shared (measured under load)")
    print(f"synthesize_cubes : {t_synth:7.2f} s  {1e3 * t_synth / total:6.2f} ms/cube  "
          f"{total / t_synth:7.1f} cubes/s")
    print(f"baseline (noise) : {t_noise:7.2f} s  {1e3 * t_noise / total:6.2f} ms/cube  "
          f"ratio {t_synth / t_noise:.2f}")


if __name__ == "__main__":
    main()
