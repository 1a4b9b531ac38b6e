"""What the causal stream (``mmsnap live``, equal to ``mmsnap replay`` of its
recording, docs/LIVE.md "Live and replay") decides differently from ``mmsnap
fuse``, on a simulated recording with the real physics (multipath, clutter):
the rows that differ between ``mmsnap replay --delay 0`` and ``mmsnap fuse``,
and between ``mmsnap replay --delay 9`` (the checks' look-around) and fuse,
counted by (stream status, fuse status). Both with the vectorized solver.

Usage::

    python tools/live_vs_offline.py OUT_DIR [SEED]
"""

from __future__ import annotations

import json
import sys
from collections import Counter
from pathlib import Path

import numpy as np

from mmsnap_graph.app.cli import main as mmsnap
from mmsnap_graph.data.results import Status
from mmsnap_graph.io import read_fused, write_recording
from mmsnap_graph.sim import SimulationOptions, simulate_recording


def _replayed(path: Path) -> dict:
    out = {}
    for r in map(json.loads, path.read_text().splitlines()):
        for state, status, index in zip(r["state"], r["status"], r["detection_index"]):
            out[(r["frame"], tuple(index))] = (int(status), np.asarray(state))
    return out


def main(out_dir: str, seed: int = 0) -> None:
    d = Path(out_dir)
    d.mkdir(parents=True, exist_ok=True)
    rec = simulate_recording("C", "straight", SimulationOptions(n_targets=2, frame_period_s=0.05),
                             levels=["centroids"], n_frames=400, seed=seed)
    write_recording(d / "sim.h5", rec, overwrite=True)
    (d / "cal.json").write_text(json.dumps({"nodes": {
        n: {"pose": list(map(float, p))} for n, p in rec.truth.node_poses.items()}}))
    common = ["--calibration", str(d / "cal.json"), "--solver", "vectorized", "--overwrite"]
    for delay in (0, 9):
        mmsnap(["replay", str(d / "sim.h5"), "--delay", str(delay), "-o",
                str(d / f"replay{delay}.jsonl"), "--summary"] + common)
    mmsnap(["fuse", str(d / "sim.h5"), "-o", str(d / "fused.h5"), "--no-progress"] + common)
    f = read_fused(d / "fused.h5")
    offline = {(int(fr), tuple(int(i) for i in idx)): (int(st), np.asarray(x))
               for fr, idx, st, x in zip(f.frame, f.detection_index, f.status, f.state)}
    for delay in (0, 9):
        rows = _replayed(d / f"replay{delay}.jsonl")
        assert set(rows) == set(offline), "the stream and fuse grouped differently"
        differ = [k for k in offline if rows[k][0] != offline[k][0] or not np.allclose(
            rows[k][1], offline[k][1], rtol=0, atol=1e-9, equal_nan=True)]
        kinds = Counter((Status(rows[k][0]).name, Status(offline[k][0]).name) for k in differ)
        print(f"replay --delay {delay} vs fuse: {len(differ)} of {len(offline)} rows differ; "
              f"(stream status, fuse status): {dict(kinds.most_common())}")


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]) if len(sys.argv) > 2 else 0)
