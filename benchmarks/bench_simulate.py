"""Speed of the simulator: raw-ADC synthesis of a two-node recording.

Target (issue 3): a 600-frame two-node recording with Table I cubes in under
a minute on 2 cores. Prints the wall time of ``simulate_recording`` per level
and, as the in-run baseline, a direct (non-separable) synthesis that evaluates
the full phase tensor ``(M, n_samples, n_loops, n_virtual)`` per frame.

Run: ``python benchmarks/bench_simulate.py [--frames 600] [--baseline-frames 3]``
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time

import numpy as np

from factors.models import global_to_local
from mmsnap_graph.data.radar_config import SPEED_OF_LIGHT_MPS, TABLE_I
from mmsnap_graph.sim import network_poses, simulate_recording, simulate_targets
from mmsnap_graph.sim.body import body_scatterers
from mmsnap_graph.sim.cube import scatterer_amplitude
from mmsnap_graph.sim import CLEAN


def direct_cube(cfg, p_local, v_local, amp, rng, noise_std=1.0):
    """Textbook synthesis: the phase of every scatterer at every sample."""
    r = np.hypot(p_local[:, 0], p_local[:, 1])
    sin_t = p_local[:, 0] / r
    v_rad = np.sum(v_local * p_local, axis=1) / r
    fb = 2 * (cfg.slope_hz_per_s * r + cfg.carrier_hz * v_rad) / SPEED_OF_LIGHT_MPS
    n = np.arange(cfg.n_samples)[None, :, None, None]
    tx = np.repeat(np.arange(cfg.n_tx), cfg.n_rx)
    t = ((np.arange(cfg.n_loops)[:, None] * cfg.n_tx + tx[None, :]) * cfg.chirp_period_s)
    phase = (2 * np.pi * fb[:, None, None, None] * n / cfg.sample_rate_hz
             + 4 * np.pi / cfg.wavelength_m * v_rad[:, None, None, None] * t[None, None]
             + np.pi * sin_t[:, None, None, None] * cfg.virtual_azimuth_half_wl[None, None, None])
    cube = np.sum(amp[:, None, None, None] * np.exp(1j * phase), axis=0)
    cube += noise_std / np.sqrt(2) * (rng.standard_normal(cube.shape)
                                      + 1j * rng.standard_normal(cube.shape))
    return cube.astype(np.complex64)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=600)
    ap.add_argument("--baseline-frames", type=int, default=3)
    ap.add_argument("--configuration", default="B")
    ap.add_argument("--memmap", action="store_true",
                    help="build the cubes in memory-mapped scratch files (as mmsnap simulate "
                         "does) instead of RAM (3.5 GB for 2 x 600 frames)")
    args = ap.parse_args()
    cfg = TABLE_I
    print(f"load average before: {os.getloadavg()[0]:.2f}; threads: OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS', 'unset')}, "
          f"cpus={os.cpu_count()}")

    t0 = time.perf_counter()
    simulate_recording(args.configuration, "random", CLEAN, levels=("centroids", "point_cloud"),
                       n_frames=args.frames, seed=0)
    t_light = time.perf_counter() - t0
    print(f"centroids + point clouds, 2 nodes x {args.frames} frames: {t_light:.2f} s")

    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        rec = simulate_recording(args.configuration, "random", CLEAN, levels=("cube",),
                                 n_frames=args.frames, seed=0,
                                 cube_memmap_dir=tmp if args.memmap else None)
        t_cube = time.perf_counter() - t0
        n_cubes = sum(n.cube.shape[0] for n in rec.nodes.values())
        del rec
    per_frame = t_cube / n_cubes
    where = "memory-mapped" if args.memmap else "in RAM"
    print(f"raw ADC cubes (Table I, {cfg.cube_shape}, {where}), 2 nodes x {args.frames} frames: "
          f"{t_cube:.1f} s ({1e3 * per_frame:.1f} ms per node-frame)")
    t600 = per_frame * 2 * 600
    print(f"600-frame two-node recording: {t600:.1f} s "
          f"({'measured' if args.frames == 600 else 'extrapolated'}); target < 60 s: "
          f"{'PASS' if t600 < 60 else 'FAIL'}")

    # Baseline: the direct synthesis for a few frames of node S1.
    pose = network_poses(args.configuration)["S1"]
    states = simulate_targets(args.configuration, "random", n_frames=args.baseline_frames, seed=0)[0]
    body = body_scatterers(states, cfg.frame_period_s)
    rng = np.random.default_rng(0)
    t0 = time.perf_counter()
    for f in range(args.baseline_frames):
        p = global_to_local(body.positions_m[f], pose)
        c, s = np.cos(pose[2]), np.sin(pose[2])
        v = body.velocities_mps[f] @ np.array([[c, s], [-s, c]]).T
        amp = scatterer_amplitude(cfg, body.rcs_m2, np.hypot(p[:, 0], p[:, 1]))
        direct_cube(cfg, p, v, amp, rng)
    t_direct = (time.perf_counter() - t0) / args.baseline_frames
    print(f"baseline direct synthesis: {1e3 * t_direct:.1f} ms per node-frame "
          f"({body.positions_m.shape[1]} scatterers, no clutter)")
    print(f"speed-up of simulate_recording's cube level over the direct synthesis: "
          f"{t_direct / per_frame:.1f}x")


if __name__ == "__main__":
    main()
