"""Robust fusion against ghost models it was not written with
(:mod:`mmsnap_graph.sim.real.ghosts`): 3-node networks, 10% and 20% of each node's
centroids corrupted, fused as ``mmsnap fuse`` does by default (a node's
centroids of one body merged, ``robust="gate"`` with the motion check and its
coverage check, then the walls learned from the multipath images and one
target per body, :func:`~mmsnap_graph.fusion.recording.room.screen_room`),
with and without the room's bounds (``--bounds``), on the simulator's clean
model with its centroid sigmas.

Targets: position RMSE of the rows kept within 1.3x / 1.6x of the clean run,
their NEES inside the 95% chi-square band, a ghost target (a kept row more
than 0.5 m from the truth) in at most 2% of the frames. Combinations that miss
a target are strict xfails quoting the measurement and the reason.
"""

from __future__ import annotations

import numpy as np
import pytest
from mmsnap_graph.evaluation import chi2_mean_interval, nees

from _shared import POSES_BC
from mmsnap_graph.fusion.recording.room import DEFAULT_BODY_M, RoomBounds, screen_room
from mmsnap_graph.fusion.recording.sequence import fuse_recording
from mmsnap_graph.sim import SimulationOptions, simulate_recording
from mmsnap_graph.sim.real.ghosts import ghost_centroids
from mmsnap_graph.sim.simulator import CENTROID_NOISE
from _fusion import config

NETWORK = {"S1": POSES_BC[0], "S2": POSES_BC[1], "S3": POSES_BC[2]}
SEEDS = (10, 11)
FACTOR = {0.1: 1.3, 0.2: 1.6}
CASES = [
    ("near_range", 0.1, False, None), ("near_range", 0.2, False, None),
    ("uniform", 0.1, False, None), ("uniform", 0.2, False, None),
    ("mirror", 0.1, False, None), ("mirror", 0.2, False, None),
    ("mirror", 0.1, True, None), ("mirror", 0.2, True, None),
    ("split", 0.1, False, None), ("split", 0.2, False, None),
]


def _tally(fused, rec, acc):
    ok = fused.success
    err = fused.state - rec.truth.state[fused.frame]     # one target: truth row = frame
    pos = np.hypot(err[:, 0], err[:, 1])
    acc["se"] += float(np.sum(pos[ok] ** 2))
    acc["nees"].append(nees(err[ok], fused.covariance[ok]))
    frames, at = np.unique(fused.frame, return_inverse=True)
    far = np.bincount(at, weights=ok & (pos > 0.5), minlength=frames.size)
    acc["ghost_frames"] += int(np.sum(far > 0))
    acc["frames"] += frames.size


@pytest.fixture(scope="module")
def results():
    out = {}
    for seed in SEEDS:
        rec = simulate_recording(NETWORK, "random",
                                 SimulationOptions(physics=None, known_poses=True),
                                 levels=("centroids",), n_frames=600, seed=seed)
        xy = rec.truth.state[:, :2]
        # The generator's default room: the walk's box 1 m wider.
        room = RoomBounds(x_min=xy[:, 0].min() - 1, x_max=xy[:, 0].max() + 1,
                          y_min=xy[:, 1].min() - 1, y_max=xy[:, 1].max() + 1)
        runs = [("clean", 0.0, rec)] + [(k, p, ghost_centroids(rec, k, p, seed=seed + 100))
                                        for k, p in dict.fromkeys((k, p) for k, p, _, _ in CASES)]
        for k, p, data in runs:
            fused = fuse_recording(data, config(robust="gate"), noise=CENTROID_NOISE, progress=False)
            for bounds in (False, True):
                screened, _ = screen_room(fused, body_m=DEFAULT_BODY_M,
                                          bounds=room if bounds else None)
                acc = out.setdefault((k, p, bounds),
                                     {"se": 0.0, "nees": [], "ghost_frames": 0, "frames": 0})
                _tally(screened, rec, acc)
    return out


def _rmse(acc):
    return np.sqrt(acc["se"] / sum(n.size for n in acc["nees"]))


@pytest.mark.slow
@pytest.mark.parametrize("kind, p, bounds", [
    pytest.param(k, p, b, marks=[pytest.mark.xfail(strict=True, reason=why)] if why else [])
    for k, p, b, why in CASES])
def test_robust_fusion_holds_against_the_ghost_model(results, kind, p, bounds):
    """Measured (seeds 10-11, 1,200 frames): clean 0.0528 m, NEES 4.04; near_range 1.15x /
    1.30x, NEES 4.01 / 3.93; uniform 1.14x / 1.28x, NEES 4.04 / 3.97; split 1.00x / 1.00x
    (the halves merged into one centroid per body), NEES 4.04; mirror 1.00x / 1.00x, NEES
    4.04, no ghost target (1 and 8 images flagged beyond a learned wall; without the learned
    walls 3.66x / 8.04x, NEES 22.7 / 74.9, ghost targets in 0.1% / 0.7% of the frames);
    mirror with --bounds 1.00x, NEES 4.04."""
    acc, clean = results[(kind, p, bounds)], results[("clean", 0.0, bounds)]
    assert _rmse(acc) <= FACTOR[p] * _rmse(clean), (_rmse(acc), _rmse(clean))
    n = np.concatenate(acc["nees"])
    lo, hi = chi2_mean_interval(4, n.size, 0.95)
    assert lo < n.mean() < hi, (n.mean(), lo, hi)
    assert acc["ghost_frames"] <= 0.02 * acc["frames"], acc["ghost_frames"]
