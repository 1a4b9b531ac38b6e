"""The TI user's path on the shared recordings: the recorder's saved frames
dumped as they are stored (10-frame stacks, room frame, static points in),
then ``mmsnap import table --destack --room-pose --mount --height-band
0.2,2.0``, ``process``, ``calibrate``, ``fuse``, and S2 against the tape.

Per recording the tool prints S2's error against the tape-measured mounting
(1.70 m, 1.65 m, 90 deg) in S2's body tangent, the reported sigma, the
mounting sigma (the reported covariance with each radar's angle bias,
``calibration.angle_bias``) and the share of fused rows inside the room box.

Run from the repository: ``python tools/measure_destack_path.py SOURCE_DIR
--folder OUT`` with SOURCE_DIR the folder of the recorder's pickles (see
``data/real/darksz/README.md``).
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
TAPE_S2 = (1.70, 1.65, 90.0)
#: stem -> (S2 height (m), room box x_min, x_max, y_min, y_max)
RECORDINGS = {"multiple_tracking": (1.1, (-2.0, 1.6, 0.0, 3.6)),
              "fall_detection": (2.45, (-1.7, 1.6, 0.0, 3.6))}


def _make_tables():
    spec = importlib.util.spec_from_file_location(
        "make_tables", ROOT / "data" / "real" / "darksz" / "make_tables.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def stacked_table(saved: list[dict], radar: str, path: Path, period: float = 0.05) -> int:
    """Every saved frame's points as stored (the stack), saved frame k
    stamped k * period; returns the rows written."""
    lines, n = ["frame,time_s,x_m,y_m,z_m,doppler_mps,snr_db"], 0
    for k, frame in enumerate(saved):
        pts = np.asarray(frame[radar])
        for x, y, z, v, s in pts.tolist():
            lines.append(f"{k},{k * period:.2f},{x!r},{y!r},{z!r},{v!r},{s / 10.0!r}")
            n += 1
    path.write_text("\n".join(lines) + "\n")
    return n


def _mmsnap(*args: str) -> str:
    out = subprocess.run([sys.executable, "-m", "mmsnap_graph", *args], capture_output=True,
                         text=True)
    if out.returncode not in (0, 1):
        raise RuntimeError(f"mmsnap {' '.join(args)} failed:\n{out.stderr[-2000:]}")
    return out.stdout


def measure(stem: str, saved: list[dict], folder: Path) -> dict:
    from mmsnap_graph.calibration import pose_tangent_error
    from mmsnap_graph.calibration.angle_bias import mounting_covariance
    from mmsnap_graph.io.fused import read_fused

    height, room = RECORDINGS[stem]
    tables = {}
    for radar, node in (("IWR1843_Ori", "S1"), ("IWR1843_Side", "S2")):
        tables[node] = folder / f"{stem}_stacked_{node}.csv"
        stacked_table(saved, radar, tables[node])
    out = folder / f"{stem}_stacked.h5"
    _mmsnap("import", "table", "--node", f"S1={tables['S1']}", "--node", f"S2={tables['S2']}",
            "--destack", "--frame-period", "0.05", "--mount", "S1=0.8,0", "--mount",
            f"S2={height},0", "--room-pose", "S1=0,0,0", "--room-pose",
            "S2={},{},{}".format(*TAPE_S2), "--height-band", "0.2,2.0", "-o", str(out),
            "--overwrite")
    _mmsnap("process", str(out), "--no-progress")
    _mmsnap("calibrate", str(out), "--overwrite", "--no-progress")
    cal = json.loads(out.with_suffix(".calibration.json").read_text())["nodes"]["S2"]
    _mmsnap("fuse", str(out), "--overwrite", "--no-progress")
    fused = read_fused(out)
    ok = np.asarray(fused.success, dtype=bool)
    xy = np.asarray(fused.state)[ok, :2]
    inside = ((xy[:, 0] >= room[0]) & (xy[:, 0] <= room[1]) & (xy[:, 1] >= room[2])
              & (xy[:, 1] <= room[3]))
    pose, cov = np.asarray(cal["pose"]), np.asarray(cal["covariance"])
    tape = np.array([TAPE_S2[0], TAPE_S2[1], np.deg2rad(TAPE_S2[2])])
    err = pose_tangent_error(pose, tape)
    return {"stem": stem, "error": err.tolist(), "sigma": np.sqrt(np.diag(cov)).tolist(),
            "mounting_sigma": np.sqrt(np.diag(mounting_covariance(pose, cov))).tolist(),
            "position_error_m": float(np.hypot(*(pose[:2] - tape[:2]))),
            "inside_share": float(inside.mean()) if inside.size else float("nan"),
            "fused_rows": int(ok.sum())}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("source", type=Path, help="folder of the recorder's pickles")
    p.add_argument("--folder", type=Path, required=True)
    args = p.parse_args(argv)
    args.folder.mkdir(parents=True, exist_ok=True)
    mt = _make_tables()
    for source, (stem, md5) in mt.RECORDINGS.items():
        r = measure(stem, mt.load_frames(args.source / source, md5), args.folder)
        e, s, m = r["error"], r["sigma"], r["mounting_sigma"]
        print(f"{stem} (--destack path): S2 {r['position_error_m']:.3f} m, "
              f"{np.rad2deg(e[2]):+.2f} deg from the tape; body error ({e[0]:+.3f} m, "
              f"{e[1]:+.3f} m); reported sigma ({s[0]:.3f} m, {s[1]:.3f} m, "
              f"{np.rad2deg(s[2]):.2f} deg), mounting sigma ({m[0]:.3f} m, {m[1]:.3f} m, "
              f"{np.rad2deg(m[2]):.2f} deg); heading error / mounting sigma with the tape's "
              f"3 deg {np.rad2deg(e[2]) / np.hypot(np.rad2deg(m[2]), 3.0):+.2f}; fused rows "
              f"inside the room {100 * r['inside_share']:.1f}% of {r['fused_rows']}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
