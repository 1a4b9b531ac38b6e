"""Accuracy of the decalibration monitor (docs/CALIBRATION.md, "Noticing a moved radar").

    python benchmarks/bench_monitor.py [--detection] [--false-alarms] [--hours H] [--seeds N]
        [--frames F] [--bump-at-s T] [--networks C,B] [--bumps "2deg,10cm x"]

1. --detection (default on): bumped recordings (``sim.bump``, one random
   walker, the bump at 60 s, 800 frames of 150 ms) of configurations C, B, A
   and a three-node network, bumps of 10 cm along x, 10 cm along y and
   2 degrees; per seed the detection delay, the estimated change time, and
   the re-calibrated pose's error in sigmas (body tangent) and Mahalanobis
   distance (chi-square 3 under a consistent covariance). ``--frames`` and
   ``--bump-at-s`` set the length and the bump's time (e.g. ``--frames 48000
   --bump-at-s 3600``: a bump an hour into a 2-hour recording), ``--networks``
   and ``--bumps`` which rows run.
2. --false-alarms: clean recordings of ``--hours`` simulated hours per network
   and seed (24,000 frames per hour); prints the number of changes declared,
   the hours and the largest statistic against the threshold.

Accuracy only (no timing ratios): figures are deterministic given the seeds.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from mmsnap_graph.calibration.monitor.decalibration import DEFAULT_THRESHOLD, monitor_recording
from mmsnap_graph.sim import simulate_recording
from mmsnap_graph.sim.bump import simulate_bumped_recording
from mmsnap_graph.sim import SimulationOptions

TRIANGLE = {"S1": (0.0, 0.0, 0.0), "S2": (0.0, 7.0, np.pi), "S3": (-3.5, 3.5, -np.pi / 2)}
NETWORKS = {"C": "C", "B": "B", "A": "A", "triangle": TRIANGLE}
BUMPS = {"10cm x": (0.1, 0.0, 0.0), "10cm y": (0.0, 0.1, 0.0),
         "2deg": (0.0, 0.0, np.deg2rad(2.0))}
BUMP_TIME_S = 60.0
N_FRAMES = 800


def _tangent_error(pose, truth):
    d = truth[:2] - pose[:2]
    c, s = np.cos(pose[2]), np.sin(pose[2])
    dphi = (truth[2] - pose[2] + np.pi) % (2 * np.pi) - np.pi
    return -np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1], dphi])


def detection(seeds: int, networks=tuple(NETWORKS), bumps=tuple(BUMPS), *,
              n_frames: int = N_FRAMES, bump_time_s: float = BUMP_TIME_S) -> dict:
    """Print the detection table of ``networks`` x ``bumps`` (names of
    :data:`NETWORKS` and :data:`BUMPS`) on ``seeds`` seeds; returns
    (network, bump) -> the Mahalanobis distances of the re-calibrated poses
    (NaN where none succeeded after a detection)."""
    print(f"detection: bump at {bump_time_s:.0f} s, {n_frames} frames, threshold "
          f"{DEFAULT_THRESHOLD:.1f}; node S2 (triangle: S3)")
    print(f"{'network':<9}{'bump':<8}{'seed':>5}{'delay_s':>9}{'change_s':>9}{'false':>6}"
          f"{'err_sigmas (x_b, y_b, phi)':>30}{'mahal':>7}")
    out = {}
    for net_name in networks:
        network = NETWORKS[net_name]
        node = "S3" if net_name == "triangle" else "S2"
        for bump_name in bumps:
            bump = BUMPS[bump_name]
            out[net_name, bump_name] = distances = []
            delays = []
            for seed in range(seeds):
                rec = simulate_bumped_recording(network, "random", physics=None, node=node, bump=bump,
                                                bump_time_s=bump_time_s, n_frames=n_frames,
                                                seed=seed)
                res = monitor_recording(rec)
                t_bump = rec.metadata["bump_time_s"]
                hits = [c for c in res.changes if c.node == node and c.detection_time_s >= t_bump]
                false = len(res.changes) - len(hits[:1])
                if not hits:
                    print(f"{net_name:<9}{bump_name:<8}{seed:>5}{'missed':>9}{'':>9}{false:>6}"
                          f"   (largest statistic after the bump "
                          f"{np.nanmax(res.statistics[rec.metadata['bump_frame']:]):.1f})")
                    delays.append(np.inf)
                    distances.append(np.nan)
                    continue
                c = hits[0]
                delays.append(c.detection_time_s - t_bump)
                text, mahal = "", np.nan
                rc = [r for r in res.recalibrations if r.change is c]
                if rc and rc[0].fit.success:
                    truth = np.array([rec.metadata[k] for k in
                                      ("bumped_x_m", "bumped_y_m", "bumped_phi_rad")])
                    fit = rc[0].fit
                    err = _tangent_error(fit.pose, truth)
                    z = err / np.sqrt(np.diag(fit.covariance))
                    mahal = float(err @ np.linalg.solve(fit.covariance, err))
                    text = f"{'(' + ', '.join(f'{v:+.2f}' for v in z) + ')':>30}{mahal:7.2f}"
                distances.append(mahal)
                print(f"{net_name:<9}{bump_name:<8}{seed:>5}{delays[-1]:9.2f}{c.time_s:9.2f}"
                      f"{false:>6}{text}")
            d = np.array(delays)
            print(f"  -> {net_name} {bump_name}: detected {np.isfinite(d).sum()}/{d.size}, "
                  f"delay median {np.median(d):.2f} s, max {np.max(d):.2f} s")
    return out


def false_alarms(hours: float, seeds: int) -> None:
    n_frames = int(round(hours * 3600 / 0.15))
    print(f"false alarms: clean recordings, {hours:g} h ({n_frames} frames) per network and seed")
    total_alarms, total_hours = 0, 0.0
    for net_name in ("C", "triangle"):
        for seed in range(100, 100 + seeds):
            t0 = time.perf_counter()
            rec = simulate_recording(NETWORKS[net_name], "random",
                                     SimulationOptions(physics=None, known_poses=True),
                                     levels=("centroids",), n_frames=n_frames, seed=seed)
            res = monitor_recording(rec)
            total_alarms += len(res.changes)
            total_hours += hours
            print(f"{net_name:<9} seed {seed}: {len(res.changes)} changes in {hours:g} h; "
                  f"largest statistic {np.nanmax(res.statistics):.1f} (threshold "
                  f"{res.threshold:.1f}); {time.perf_counter() - t0:.0f} s")
    print(f"  -> {total_alarms} false alarms in {total_hours:g} simulated network-hours")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--detection", action="store_true")
    ap.add_argument("--false-alarms", action="store_true")
    ap.add_argument("--hours", type=float, default=1.0)
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--frames", type=int, default=N_FRAMES)
    ap.add_argument("--bump-at-s", type=float, default=BUMP_TIME_S)
    ap.add_argument("--networks", default=",".join(NETWORKS))
    ap.add_argument("--bumps", default=",".join(BUMPS))
    args = ap.parse_args()
    if not args.false_alarms or args.detection:
        detection(args.seeds, tuple(args.networks.split(",")), tuple(args.bumps.split(",")),
                  n_frames=args.frames, bump_time_s=args.bump_at_s)
    if args.false_alarms:
        false_alarms(args.hours, max(1, args.seeds // 2))


if __name__ == "__main__":
    main()
