"""Speed (and, with --accuracy, accuracy) of self-calibration.

    python benchmarks/bench_calibration.py [--quick] [--accuracy]

Prints, with wall-clock medians over repetitions:

1. the pairwise closed form for K = 600 frames against ``gtsam.Pose2.Align``
   on the same points (the in-run baseline), and how it grows with K;
2. the joint calibration graph (2 nodes x K frames), with the numpy presolve
   (default) against plain GTSAM LM from the closed form (baseline), and how
   it grows with frames and nodes;
3. the pose graph for N nodes;
4. with --accuracy: the seeded Monte Carlo of closed form vs joint graph
   (registration error, pose errors, NEES) on the paper's configurations.

The machine is shared: figures vary with load; the ratios in one run are
the comparable numbers.
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import gtsam
import numpy as np

from mmsnap_graph.calibration import JointOptions
from factors.models import global_to_local, local_to_global
from mmsnap_graph.data.calibration import PairwiseCalibration
from mmsnap_graph.calibration import (
    closed_form_calibration,
    closed_form_pose,
    joint_calibration,
    pose_tangent_error,
    pose_graph_calibration,
)
from mmsnap_graph.sim.scenes import COMMON_AREA_CENTERS, PAPER_CONFIGURATIONS, synthetic_scene
from mmsnap_graph.data.noise import MeasurementNoise
from mmsnap_graph.data.recording import Detections

NOISE = MeasurementNoise(range_m=0.035, omega_rad=0.2, doppler_mps=0.18)


def _median_time(fn, repeat, number=1):
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        for _ in range(number):
            fn()
        times.append((time.perf_counter() - t0) / number)
    return float(np.median(times))


def _dets(scene):
    return {n: Detections(frame=scene.frame, range_m=z[:, 0], omega_rad=z[:, 1],
                          doppler_mps=z[:, 2]) for n, z in scene.measurements.items()}


def bench_closed_form(quick):
    print("== pairwise closed form (paper eqs. 12-14) ==")
    rng = np.random.default_rng(0)
    scene = synthetic_scene(PAPER_CONFIGURATIONS["C"], center_m=COMMON_AREA_CENTERS["C"],
                            n_frames=600, noise=NOISE, rng=rng)
    a, b = scene.local_points_m["S1"], scene.local_points_m["S2"]
    at, bt = np.ascontiguousarray(a.T), np.ascontiguousarray(b.T)
    n = 200 if quick else 2000
    t_bare = _median_time(lambda: closed_form_pose(a, b), 7, n)
    t_full = _median_time(lambda: closed_form_calibration(a, b), 7, n)
    t_align = _median_time(lambda: gtsam.Pose2.Align(at, bt), 7, n)
    print(f"K=600: closed_form_pose {t_bare * 1e6:8.1f} us | closed_form_calibration "
          f"(validation + covariance) {t_full * 1e6:8.1f} us | gtsam.Pose2.Align "
          f"{t_align * 1e6:8.1f} us | bare/Align {t_bare / t_align:.2f}, full/Align "
          f"{t_full / t_align:.2f}")
    for k in (150, 600, 2400, 9600):
        pts = rng.uniform(-3, 3, size=(k, 2)) + [0, 4]
        pb = global_to_local(pts, np.array([0.0, 7.0, np.pi])) + rng.normal(size=(k, 2)) * 0.1
        t = _median_time(lambda: closed_form_calibration(pts, pb), 5, max(n // 10, 20))
        ta = _median_time(lambda: gtsam.Pose2.Align(pts.T.copy(), pb.T.copy()), 5,
                          max(n // 10, 20))
        print(f"  K={k:5d}: closed_form_calibration {t * 1e6:9.1f} us   Align {ta * 1e6:9.1f} us")


def bench_joint(quick):
    print("== joint calibration graph (poses + target states, LM, Marginals) ==")
    frames = (150, 300, 600) if quick else (150, 300, 600, 1200)
    for motion in (False, True):
        for k in frames:
            rng = np.random.default_rng(1)
            scene = synthetic_scene(PAPER_CONFIGURATIONS["C"], center_m=COMMON_AREA_CENTERS["C"],
                                    n_frames=k, noise=NOISE, rng=rng)
            d = _dets(scene)
            kw = dict(noise=NOISE, frame_period_s=0.15)
            opts = JointOptions(motion=motion, sigma_a_mps2=0.5)
            t = _median_time(lambda: joint_calibration(d, opts, **kw), 3)
            t_gauss = _median_time(
                lambda: joint_calibration(d, dataclasses.replace(opts, robust=None), **kw), 3)
            line = (f"  2 nodes x {k:4d} frames, motion={'on ' if motion else 'off'}: "
                    f"Cauchy + inlier refit {t:6.3f} s | Gaussian {t_gauss:6.3f} s")
            if k == 600:
                t_plain = _median_time(lambda: joint_calibration(
                    d, dataclasses.replace(opts, presolve=False), **kw), 1)
                line += f" | plain LM (baseline) {t_plain:6.3f} s, ratio {t / t_plain:.2f}"
            print(line)
    for n_nodes in (2, 3, 4):
        poses = {"S1": np.zeros(3), "S2": np.array([5.0, 5.0, np.pi / 2]),
                 "S3": np.array([4.0, 0.0, np.pi / 6]), "S4": np.array([0.0, 7.0, np.pi])}
        poses = dict(list(poses.items())[:n_nodes])
        rng = np.random.default_rng(2)
        scene = synthetic_scene(poses, center_m=np.array([1.5, 3.5]), n_frames=300, extent_m=1.0,
                                noise=NOISE, rng=rng)
        d = _dets(scene)
        t = _median_time(lambda: joint_calibration(d, noise=NOISE), 3)
        print(f"  {n_nodes} nodes x 300 frames: {t:6.3f} s")


def bench_pose_graph(quick):
    print("== pose graph of pairwise estimates ==")
    rng = np.random.default_rng(3)
    for n in (4, 16, 64):
        names = [f"S{i + 1}" for i in range(n)]
        poses = {s: np.array([rng.uniform(-20, 20), rng.uniform(-20, 20), rng.uniform(-3, 3)])
                 for s in names}
        poses["S1"] = np.zeros(3)
        edges = []
        for i in range(n):
            for j in (i + 1, i + 2):
                if j < n:
                    a, b = names[i], names[j]
                    rel = gtsam.Pose2(*poses[a]).between(gtsam.Pose2(*poses[b]))
                    edges.append(PairwiseCalibration(node_a=a, node_b=b,
                                                     pose=[rel.x(), rel.y(), rel.theta()],
                                                     covariance=np.diag([1e-3, 1e-3, 1e-4])))
        t = _median_time(lambda: pose_graph_calibration(names, edges), 5)
        print(f"  {n:3d} nodes, {len(edges):3d} edges: {t * 1e3:7.2f} ms")


def bench_accuracy(quick):
    print("== Monte Carlo: closed form (detections -> local xy) vs joint graph (raw "
          "measurements), same frames ==")
    trials = 6 if quick else 12

    def reg(est, truth, pts):
        loc = global_to_local(pts, truth)
        return float(np.sqrt(np.mean(np.sum((local_to_global(loc, est) - pts) ** 2, axis=1))))

    for label, sig, k in (("paper sigmas (0.035 m, pi/4, 0.18 m/s)", MeasurementNoise(), 300),
                          ("omega 0.2 rad", NOISE, 300)):
        print(f"  {label}, K={k}, {trials} trials, motion factors on (sigma_a 0.5):")
        for cfg in "ABC":
            r_cf, r_jt, e_cf, e_jt, nees = [], [], [], [], []
            for t in range(trials):
                rng = np.random.default_rng(400 + t)
                s = synthetic_scene(PAPER_CONFIGURATIONS[cfg], center_m=COMMON_AREA_CENTERS[cfg],
                                    n_frames=k, noise=sig, rng=rng)
                cf = closed_form_calibration(s.local_points_m["S1"], s.local_points_m["S2"])
                jt = joint_calibration(_dets(s), JointOptions(motion=True, sigma_a_mps2=0.5), noise=sig, frame_period_s=0.15)
                truth = s.poses["S2"]
                r_cf.append(reg(cf.pose, truth, s.truth[:, :2]))
                r_jt.append(reg(jt.poses["S2"], truth, s.truth[:, :2]))
                e_cf.append(pose_tangent_error(cf.pose, truth))
                e = pose_tangent_error(jt.poses["S2"], truth)
                e_jt.append(e)
                nees.append(e @ np.linalg.solve(jt.covariances["S2"], e))

            def rms(x):
                return float(np.sqrt(np.mean(np.square(x))))

            e_cf, e_jt = np.array(e_cf), np.array(e_jt)
            print(f"    {cfg}: registration RMS cf {rms(r_cf):.3f} m, joint {rms(r_jt):.3f} m "
                  f"(-{1 - rms(r_jt) / rms(r_cf):.0%}) | position cf "
                  f"{rms(np.hypot(e_cf[:, 0], e_cf[:, 1])):.3f} joint "
                  f"{rms(np.hypot(e_jt[:, 0], e_jt[:, 1])):.3f} m | heading cf "
                  f"{np.degrees(rms(e_cf[:, 2])):.2f} joint {np.degrees(rms(e_jt[:, 2])):.2f} deg"
                  f" | joint NEES {np.mean(nees):.2f}")


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="fewer repetitions and sizes")
    p.add_argument("--accuracy", action="store_true", help="also run the Monte Carlo")
    args = p.parse_args()
    bench_closed_form(args.quick)
    bench_joint(args.quick)
    bench_pose_graph(args.quick)
    if args.accuracy:
        bench_accuracy(args.quick)


if __name__ == "__main__":
    main()
