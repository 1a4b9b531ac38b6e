"""Random layouts through the CLI (tools/random_layouts.py): simulate with the
real model, process, calibrate, fuse, evaluate; every run's fused NEES within
1.5x of its 4 dof (neither too small nor too large) and its position RMSE of
the successful rows <= 0.2 m, and the covariance self-check of ``fuse``
agreeing without truth (it fires on the same run fused with 0.3x sigmas).

The runs: the issue's three-radar layout at 20 fps (one radar's one-bounce
images at the far wall: NEES 18.3 before the coverage check), a random
three-radar layout with two walkers at 20 fps (24 images behind a radar
that no other radar covers, 6-7 m off: NEES 47.7, RMSE 1.08 m before the
placement check), two radars 2.2 m apart looking the same way with two
walkers at 20 fps (their mirror images through a side wall fused from both
radars, which taught no wall: NEES 9.83, RMSE 0.356 m before), and the
paper's B at 20 fps. ``python
tools/random_layouts.py --runs 16 --paper --scales 0.3,3`` runs more.
"""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import pytest

TOOL = Path(__file__).resolve().parents[1] / "tools" / "random_layouts.py"


def _tool():
    spec = importlib.util.spec_from_file_location("random_layouts", TOOL)
    mod = importlib.util.module_from_spec(spec)
    sys.modules.setdefault(spec.name, mod)      # its dataclasses look their module up
    spec.loader.exec_module(sys.modules[spec.name])
    mod = sys.modules[spec.name]
    return mod


def _runs(tool):
    deg = math.radians
    return [
        tool.Run(name="issue", nodes=(("S1", 0.0, 0.0, 0.0), ("S2", 4.0, 0.0, deg(60)),
                                      ("S3", 2.0, 6.0, deg(180))),
                 configuration=None, frame_period_s=0.05, targets=1, seed=3, frames=600),
        tool.Run(name="R09", nodes=(("S1", 0.0, 0.0, 0.0), ("S2", 1.583, 5.119, deg(137.75)),
                                    ("S3", -6.762, 2.464, deg(-83.86))),
                 configuration=None, frame_period_s=0.05, targets=2, seed=1999344461,
                 frames=600),
        tool.Run(name="R08", nodes=(("S1", 0.0, 0.0, 0.0), ("S2", -2.142, 0.478, deg(4.09))),
                 configuration=None, frame_period_s=0.05, targets=2, seed=319457530,
                 frames=600),
        tool.Run(name="B@50ms", nodes=None, configuration="B", frame_period_s=0.05, targets=1,
                 seed=0, frames=300),
    ]


#: Runs that miss a target today (strict: they must fail until it is reached).
XFAIL = {3: ("B at 20 fps, 300 frames, seed 0: NEES 6.11, RMSE 0.318 m (600 frames: 5.92, "
             "0.190 m; S1's one-node rows 10 beyond 0.5 m, p90 0.58 m, tied to the walker: the "
             "placement check keeps them)")}


@pytest.mark.slow
@pytest.mark.parametrize("index", [pytest.param(i, marks=pytest.mark.xfail(strict=True,
                                                                          reason=XFAIL[i]))
                                   if i in XFAIL else i for i in range(4)])
def test_random_layout_runs_are_honest(index, tmp_path):
    tool = _tool()
    run = _runs(tool)[index]
    r = tool.run_one(run, tmp_path, scales=(0.3,) if index == 0 else ())
    print(f"{run.name}: NEES {r['nees']:.2f}, RMSE {r['position_rmse_m']:.3f} m, "
          f"{r['n_success']} of {r['n_truth_rows']} truth rows, self-check "
          f"{r['consistency']['verdict']}")
    assert 4 / 1.5 <= r["nees"] <= 4 * 1.5
    assert r["position_rmse_m"] <= 0.2
    assert r["consistency"]["verdict"] == "consistent"
    for s in r["scaled"]:
        assert s["nees"] > 6 and s["consistency"]["verdict"] == "over-confident"
