"""Two radars 8 m apart facing each other, one walker: how the calibrated
pose of S2 scatters against what ``mmsnap calibrate`` reports.

For each seed the tool runs the CLI chain (``mmsnap simulate --node
S1=0,0,0 --node S2=0,8,180 -t random``, the real model, then ``process``,
``calibrate``, ``fuse``), calibrates the two halves of the processed
recording (frames before and after the middle) with the library, and prints
S2's pose error against the truth in S2's body tangent ``(x_b, y_b, phi)``
(``x_b`` across the baseline, ``y_b`` along it), the reported sigma, the
sigma without the considered reflection depth (the PoseCovariance fact) and
the fused frames with two or more people. Then, per component:

- sessions: the seeds' error variance (ddof 1) over the mean reported
  variance (and over the mean variance without the depth);
- halves: the mean squared difference of the two halves over the sum of
  their reported variances (and without the depth);
- truth: the mean squared error over the reported variance (z^2).

Run from the repository, e.g. ``python tools/measure_facing.py --seeds 0-7
--frames 600 --folder facing-runs`` (extra ``mmsnap calibrate`` arguments
after ``--``).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

FACING = {"S1": (0.0, 0.0, 0.0), "S2": (0.0, 8.0, 180.0)}


def _mmsnap(*args: str) -> str:
    out = subprocess.run([sys.executable, "-m", "mmsnap_graph", *args], capture_output=True,
                         text=True)
    if out.returncode not in (0, 1):
        raise RuntimeError(f"mmsnap {' '.join(args)} failed:\n{out.stderr[-2000:]}")
    return out.stdout


def _frames_between(rec, lo: int, hi: int):
    """The recording with every level's rows of frames in [lo, hi) only."""
    nodes = {}
    for name, node in rec.nodes.items():
        changes = {}
        for level in ("point_cloud", "centroids", "tracks"):
            det = getattr(node, level)
            if det is not None:
                changes[level] = det.select((det.frame >= lo) & (det.frame < hi))
        nodes[name] = dataclasses.replace(node, **changes)
    return dataclasses.replace(rec, nodes=nodes)


def _pose_summary(cal, truth_pose) -> dict:
    from mmsnap_graph.calibration import pose_tangent_error
    from mmsnap_graph.data.calibration_facts import PoseCovariance

    cov = np.asarray(cal.covariances["S2"], dtype=float)
    full = np.sqrt(np.diag(cov))
    try:
        fact = cal.fact(PoseCovariance)
        free = (np.asarray(fact.without_depth_sigmas, dtype=float)[:3]
                if len(fact.without_depth_sigmas) else full)
    except (KeyError, LookupError, AttributeError):
        free = full
    return {"error": pose_tangent_error(cal.poses["S2"], truth_pose).tolist(),
            "sigma": full.tolist(), "sigma_without_depth": free.tolist(),
            "range_offset_m": float(cal.range_offset_m),
            "success": bool(cal.success)}


def run_seed(seed: int, frames: int, folder: Path, extra: list[str], frame_period: float) -> dict:
    from mmsnap_graph.calibration import calibrate_recording
    from mmsnap_graph.calibration.network import joint_options_for
    from mmsnap_graph.io import read_recording
    from mmsnap_graph.io.fused import read_fused

    path = folder / f"facing_{seed}.h5"
    nodes = [a for n, (x, y, p) in FACING.items() for a in ("--node", f"{n}={x:g},{y:g},{p:g}")]
    _mmsnap("simulate", *nodes, "-t", "random", "-n", str(frames), "--frame-period",
            str(frame_period), "-s", str(seed), "-o", str(path), "--overwrite", "--no-progress")
    _mmsnap("process", str(path), "--no-progress")
    rec = read_recording(path, load_cubes=False)
    truth = np.asarray(rec.truth.node_poses["S2"], dtype=float)
    _mmsnap("calibrate", str(path), "--overwrite", "--no-progress", *extra)
    cal_json = json.loads(Path(str(path).replace(".h5", ".calibration.json")).read_text())
    _mmsnap("fuse", str(path), "--overwrite", "--no-progress")
    fused = read_fused(path)
    ok = np.asarray(fused.success, dtype=bool)
    fr, counts = np.unique(np.asarray(fused.frame)[ok], return_counts=True)
    whole = calibrate_recording(rec, joint=joint_options_for(rec))
    out = {"seed": seed, "whole": _pose_summary(whole, truth),
           "cli_json_keys": sorted(cal_json)[:3],
           "fused_frames": int(fr.size), "fused_frames_2plus": int(np.sum(counts >= 2))}
    mid = frames // 2
    out["halves"] = [_pose_summary(calibrate_recording(_frames_between(rec, lo, hi),
                                                       joint=joint_options_for(rec)), truth)
                     for lo, hi in ((0, mid), (mid, frames))]
    return out


def summarise(rows: list[dict]) -> dict:
    err = np.array([r["whole"]["error"] for r in rows])
    sig = np.array([r["whole"]["sigma"] for r in rows])
    free = np.array([r["whole"]["sigma_without_depth"] for r in rows])
    h = [(np.array(r["halves"][0]["error"]), np.array(r["halves"][1]["error"]),
          np.array(r["halves"][0]["sigma"]) ** 2 + np.array(r["halves"][1]["sigma"]) ** 2,
          np.array(r["halves"][0]["sigma_without_depth"]) ** 2
          + np.array(r["halves"][1]["sigma_without_depth"]) ** 2) for r in rows]
    d2 = np.array([(a - b) ** 2 for a, b, _, _ in h])
    return {
        "n": len(rows),
        "mean_error": err.mean(axis=0).tolist(),
        "scatter_sd": err.std(axis=0, ddof=1).tolist(),
        "reported_rms_sigma": np.sqrt(np.mean(sig**2, axis=0)).tolist(),
        "without_depth_rms_sigma": np.sqrt(np.mean(free**2, axis=0)).tolist(),
        "sessions_ratio": (err.var(axis=0, ddof=1) / np.mean(sig**2, axis=0)).tolist(),
        "sessions_ratio_without_depth": (err.var(axis=0, ddof=1)
                                         / np.mean(free**2, axis=0)).tolist(),
        "halves_ratio": np.mean(d2 / np.array([v for _, _, v, _ in h]), axis=0).tolist(),
        "halves_ratio_without_depth": np.mean(d2 / np.array([v for _, _, _, v in h]),
                                              axis=0).tolist(),
        "truth_z2": np.mean(err**2 / sig**2, axis=0).tolist(),
        "fused_2plus_share": (sum(r["fused_frames_2plus"] for r in rows)
                              / max(sum(r["fused_frames"] for r in rows), 1)),
    }


def _seeds(text: str) -> list[int]:
    if "-" in text:
        a, b = text.split("-")
        return list(range(int(a), int(b) + 1))
    return [int(s) for s in text.split(",")]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", default="0-7", help="e.g. 0-7 or 0,3,5")
    p.add_argument("--frames", type=int, default=600)
    p.add_argument("--frame-period", type=float, default=0.15)
    p.add_argument("--folder", required=True)
    p.add_argument("--json", default=None, help="write every row and the summary here")
    p.add_argument("extra", nargs="*", help="mmsnap calibrate arguments (after --)")
    args = p.parse_args(argv)
    folder = Path(args.folder)
    folder.mkdir(parents=True, exist_ok=True)
    rows = []
    for seed in _seeds(args.seeds):
        row = run_seed(seed, args.frames, folder, args.extra, args.frame_period)
        w = row["whole"]
        print(f"seed {seed}: S2 error {np.round(w['error'], 4).tolist()} sigma "
              f"{np.round(w['sigma'], 4).tolist()} without depth "
              f"{np.round(w['sigma_without_depth'], 4).tolist()} depth {w['range_offset_m']:.3f}; "
              f"halves {[np.round(hh['error'], 4).tolist() for hh in row['halves']]}; "
              f"fused frames with 2+ people {row['fused_frames_2plus']}/{row['fused_frames']}",
              flush=True)
        rows.append(row)
    summary = summarise(rows)
    for k, v in summary.items():
        print(f"{k}: {np.round(v, 4).tolist() if isinstance(v, list) else v}")
    if args.json:
        Path(args.json).write_text(json.dumps({"rows": rows, "summary": summary}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
