"""How well a recording fixes a node's heading: the joint calibration on parts
of the associated centroids, and the same chain on the simulator's real
model in the same geometry.

On a processed recording (``mmsnap process`` done) the tool runs the pose
graph and the joint graph on the centroids associated across the nodes (as
``mmsnap calibrate`` does with several people), then the joint graph again
on parts of the same associated centroids, and prints the node's heading
(and position) against a surveyed pose for each part:

- the two halves and windows of ``--window`` frames;
- each associated target track (one person for a while) with at least
  ``--min-states`` states;
- the frames with one associated target only, and those with two or more;
- the whole with an omega offset added to the node's centroids
  (``--omega-offsets``): a constant angle bias of a radar (uncompensated
  receive-channel phases) is calibrated as a heading, at almost no cost in
  the fit (the graph's final cost, last column, is comparable between these
  lines and the whole's: same states).

Each part's sigma is the joint graph's (frames independent), not the
long-run covariance of ``mmsnap calibrate``. The parts' spread against their
sigmas says whether the data fix the heading as well as the whole
recording's sigma claims.

``--simulate N`` runs ``N`` seeded simulations (the real model, or
``--clean``) of the recording's geometry: the nodes at the surveyed poses,
``--walkers`` random walks in ``--area``, ``--frames`` frames of
``--frame-period`` s, the point clouds through ``mmsnap process`` and
``mmsnap calibrate`` (extra arguments after ``--``), and prints each seed's
pose error, then the mean and the standard deviation over the seeds.

Run from the repository (the package importable), e.g. on the two-person
recording of ``data/real/darksz`` imported as in
``tests/app/test_real_recordings.py``::

    python tools/measure_heading.py mt.h5 --node S2 --surveyed 1.7,1.65,90
    python tools/measure_heading.py --simulate 12 --node S2 --surveyed 1.7,1.65,90 \\
        --area=-1.6,1.3,0.3,3.2 --room=-2.0,1.75,-0.05,3.6
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from mmsnap_graph.calibration.joint.multi_refine import refine_associated
from mmsnap_graph.calibration.joint.solve import joint_calibration
from mmsnap_graph.calibration.network import POINT_JOINT_OPTIONS, calibrate_recording
from mmsnap_graph.data.recording import Detections
from mmsnap_graph.io import read_recording, write_recording


def _floats(text: str, n: int) -> tuple[float, ...]:
    vals = tuple(float(v) for v in text.split(","))
    if len(vals) != n:
        raise argparse.ArgumentTypeError(f"{text!r}: expected {n} comma-separated numbers")
    return vals


def _pose(text: str) -> np.ndarray:
    x, y, phi_deg = _floats(text, 3)
    return np.array([x, y, np.deg2rad(phi_deg)])


class Parts:
    """The associated centroids of a recording and the joint graph on parts of them."""

    def __init__(self, path: Path, node: str, surveyed: np.ndarray):
        self.rec = read_recording(path, load_cubes=False)
        self.node, self.surveyed = node, surveyed
        names = list(self.rec.node_names)
        pg = calibrate_recording(self.rec, method="pose_graph")
        self.options = dataclasses.replace(POINT_JOINT_OPTIONS, time_offsets=False)
        out = refine_associated(self.rec, names, pg.poses, pg.covariances, pg.lag_frames,
                                noise=None, options=self.options)
        if out is None:
            raise SystemExit(f"{path}: no centroids associated across the nodes")
        self.out = out
        self.reference = names[0]

    def solve(self, keep: np.ndarray, omega_offset: float = 0.0):
        """The joint graph on the virtual frames ``keep`` (None when it fails)."""
        sub = {}
        for n, d in self.out.detections.items():
            k = np.isin(d.frame, keep)
            w = d.omega_rad[k] + (omega_offset if n == self.node else 0.0)
            sub[n] = Detections(frame=d.frame[k], range_m=d.range_m[k],
                                omega_rad=np.clip(w, -np.pi, np.pi),
                                doppler_mps=d.doppler_mps[k])
        try:
            return joint_calibration(sub, self.options, noise=self.out.noise,
                                     reference=self.reference,
                                     initial_poses={n: self.out.joint.poses[n] for n in sub},
                                     frame_period_s=self.rec.frame_period_s,
                                     lag_frames={n: 0 for n in sub})
        except Exception as exc:    # a part too small for the graph: say so, go on
            print(f"    (part not solved: {exc})")
            return None

    def line(self, label: str, keep: np.ndarray, omega_offset: float = 0.0) -> None:
        j = self.solve(keep, omega_offset)
        if j is None or self.node not in j.poses:
            print(f"{label:34s} {keep.size:5d}  not solved")
            return
        p = j.poses[self.node]
        e = p - self.surveyed
        sig = np.sqrt(np.diag(j.covariances[self.node]))
        print(f"{label:34s} {keep.size:5d}  {e[0]:+7.3f} {e[1]:+7.3f} "
              f"{np.rad2deg((e[2] + np.pi) % (2 * np.pi) - np.pi):+8.2f} "
              f"{np.rad2deg(sig[2]):7.2f} {j.final_error:9.1f}  "
              f"{'' if j.success else 'NOT converged'}")


def measure(args) -> None:
    parts = Parts(args.recording, args.node, args.surveyed)
    m = parts.out.mapping
    vf, fr, tg = m.virtual_frame, m.frame, m.target
    print(f"{args.recording}: {vf.size} associated (frame, target) states, "
          f"{m.n_targets} target tracks; {args.node}'s error against the surveyed pose")
    print(f"{'part':34s} {'states':>5s}  {'dx_m':>7s} {'dy_m':>7s} {'dphi_deg':>8s} "
          f"{'s_deg':>7s} {'cost':>9s}")
    parts.line("whole", vf)
    mid = (int(fr.min()) + int(fr.max()) + 1) // 2
    parts.line(f"first half (frames < {mid})", vf[fr < mid])
    parts.line(f"second half (frames >= {mid})", vf[fr >= mid])
    for f0 in range(int(fr.min()), int(fr.max()) + 1, args.window):
        k = (fr >= f0) & (fr < f0 + args.window)
        if np.count_nonzero(k) >= args.min_states:
            parts.line(f"frames {f0}-{f0 + args.window - 1}", vf[k])
    ids, counts = np.unique(tg, return_counts=True)
    for t in ids[np.argsort(-counts)]:
        k = tg == t
        if np.count_nonzero(k) >= args.min_states:
            parts.line(f"target track {t} (frames {fr[k].min()}-{fr[k].max()})", vf[k])
    per_frame = np.bincount(fr)[fr]
    parts.line("frames with one associated target", vf[per_frame == 1])
    parts.line("frames with two or more", vf[per_frame >= 2])
    for c in args.omega_offsets:
        parts.line(f"whole, {args.node} omega {c:+.2f} rad", vf, omega_offset=c)


def _cli(*argv) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "mmsnap_graph", *argv], capture_output=True,
                          text=True)


def simulate(args, extra: list[str]) -> None:
    from mmsnap_graph.sim import simulate_recording
    from mmsnap_graph.sim.networks import Area
    from mmsnap_graph.sim.options import SimulationOptions
    from mmsnap_graph.sim.real.physics import RealPhysics
    from mmsnap_graph.sim.trajectories import random_walk

    nodes = {"S1": np.zeros(3), args.node: args.surveyed}
    x0, x1, y0, y1 = args.area
    area = Area(x_min_m=x0, x_max_m=x1, y_min_m=y0, y_max_m=y1)
    physics = None if args.clean else RealPhysics(room=args.room)
    options = SimulationOptions(physics=physics, frame_period_s=args.frame_period,
                                n_targets=args.walkers, max_range_m=args.max_range,
                                min_range_m=0.25)
    errors = []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(args.simulate):
            rng = np.random.default_rng(1000 + seed)
            states = np.stack([random_walk(area, n_frames=args.frames,
                                           frame_period_s=args.frame_period, rng=rng)
                               for _ in range(args.walkers)])
            rec = simulate_recording(nodes, states, options, levels=("point_cloud",),
                                     n_frames=args.frames, seed=seed)
            path, out = Path(tmp) / f"sim{seed}.h5", Path(tmp) / f"sim{seed}.json"
            write_recording(path, rec)
            done = _cli("process", str(path))
            if done.returncode == 0:
                done = _cli("calibrate", str(path), "--no-write", "--json-out", str(out), *extra)
            if done.returncode != 0:
                print(f"seed {seed}: failed: {done.stderr.strip()[-300:]}")
                continue
            cal = json.loads(out.read_text())["nodes"][args.node]
            e = np.asarray(cal["pose"]) - args.surveyed
            e[2] = (e[2] + np.pi) % (2 * np.pi) - np.pi
            s = np.sqrt(np.diag(np.asarray(cal["covariance"])))
            errors.append(e)
            print(f"seed {seed}: dx {e[0]:+.3f} m, dy {e[1]:+.3f} m, dphi "
                  f"{np.rad2deg(e[2]):+.2f} deg (reported sigma {np.rad2deg(s[2]):.2f} deg)",
                  flush=True)
    if len(errors) >= 2:
        e = np.array(errors)
        print(f"{'clean' if args.clean else 'real'} model, {len(e)} seeds: dphi mean "
              f"{np.rad2deg(e[:, 2].mean()):+.2f} deg, standard deviation "
              f"{np.rad2deg(e[:, 2].std(ddof=1)):.2f} deg (median "
              f"{np.rad2deg(np.median(e[:, 2])):+.2f}); dx mean {e[:, 0].mean():+.3f} m, "
              f"dy mean {e[:, 1].mean():+.3f} m")


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    extra = argv[argv.index("--") + 1:] if "--" in argv else []
    argv = argv[:argv.index("--")] if "--" in argv else argv
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("recording", type=Path, nargs="?", help="a processed HDF5 recording")
    p.add_argument("--node", default="S2", help="the node whose heading is measured (S2)")
    p.add_argument("--surveyed", type=_pose, required=True, metavar="X,Y,PHI_DEG",
                   help="the node's surveyed pose in the reference's frame (degrees)")
    p.add_argument("--window", type=int, default=160, help="window length, frames (160)")
    p.add_argument("--min-states", type=int, default=30,
                   help="fewest associated states of a part (30)")
    p.add_argument("--omega-offsets", type=lambda s: _floats(s, len(s.split(","))),
                   default=(-0.1, 0.1), metavar="RAD,...",
                   help="omega offsets added to the node's centroids (-0.1,0.1)")
    p.add_argument("--simulate", type=int, default=0, metavar="N",
                   help="N seeded simulations of the geometry instead of a recording")
    p.add_argument("--clean", action="store_true", help="the simulator's clean model")
    p.add_argument("--walkers", type=int, default=2)
    p.add_argument("--area", type=lambda s: _floats(s, 4), default=(-1.6, 1.3, 0.3, 3.2),
                   metavar="X0,X1,Y0,Y1", help="where the walkers walk (m)")
    p.add_argument("--room", type=lambda s: _floats(s, 4), default=(-2.0, 1.75, -0.05, 3.6),
                   metavar="X0,X1,Y0,Y1", help="the walls of the multipath ghosts (m)")
    p.add_argument("--frames", type=int, default=644)
    p.add_argument("--frame-period", type=float, default=0.05)
    p.add_argument("--max-range", type=float, default=4.0)
    args = p.parse_args(argv)
    if args.simulate:
        simulate(args, extra)
    elif args.recording is None:
        p.error("give a recording or --simulate N")
    else:
        measure(args)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
