"""Robust fusion against ghost models it was not written with
(:mod:`mmsnap_graph.sim.ghosts`): 3-node networks, 10% and 20% of each node's
centroids corrupted, fused as ``mmsnap fuse`` does by default (``robust="gate"``,
motion check on), with the simulator's clean model and its centroid sigmas.

Targets: position RMSE of the rows kept within 1.3x / 1.6x of the clean run,
their NEES inside the 95% chi-square band, a ghost target (a kept row more
than 0.5 m from the truth) in at most 2% of the frames. Combinations that miss
a target are strict xfails quoting the measurement and the reason.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from _shared import POSES_BC
from mmsnap_graph.fusion.recording.sequence import fuse_recording
from mmsnap_graph.sim import SimulationOptions, simulate_recording
from mmsnap_graph.sim.ghosts import ghost_centroids
from mmsnap_graph.sim.simulator import CENTROID_NOISE

NETWORK = {"S1": POSES_BC[0], "S2": POSES_BC[1], "S3": POSES_BC[2]}
SEEDS = (10, 11)
FACTOR = {0.1: 1.3, 0.2: 1.6}
MIRROR = ("mirror images become extra fused targets: an image through a wall is a detection of "
          "a point that moves like a walker (its Doppler is the image's), so the gate and the "
          "motion check, which test each target against itself, keep it; measured (seeds 10-11, 600 frames): "
          "true-target rows unchanged (0.0529 m), ghost targets in 0.5% / 3.3% of frames, RMSE "
          "of all kept rows 5.0x / 14.3x, NEES 38 / 219. Needs a multipath test (a weaker target "
          "further along a bearing) or the room's bounds before fusion")
SPLIT = ("a body split into two centroids 0.3-0.6 m apart: each half is 0.15-0.3 m off, 1-6 "
         "sigma of the clean centroid noise (0.05 m, 0.08 rad), so the gate keeps both and "
         "fusion makes two targets; measured (seeds 10-11): RMSE 2.13x / 2.77x, NEES 7.8 / 11.4, "
         "13% / 30% more rows. Flagging a row within 0.7 m of a row of more nodes of its frame "
         "(tried) brings the rows back to 1,200 but leaves 1.50x / 1.88x, NEES 6.1 / 8.5: the "
         "half kept in a row biases it inside the noise model's cross-range sigma. Needs one "
         "cluster per body (merging a node's centroids within a body's extent) before fusion")
NEAR = ("20% replacement centroids within +-3 m of the true range: RMSE 1.34x (target met) but "
        "NEES 4.30 above the band (3.84, 4.16) (seeds 10-11): ghosts close in range to the truth "
        "pass the gate with a small bias the covariance does not hold")
CASES = [
    ("near_range", 0.1, None), ("near_range", 0.2, NEAR),
    ("uniform", 0.1, None), ("uniform", 0.2, None),
    ("mirror", 0.1, MIRROR), ("mirror", 0.2, MIRROR),
    ("split", 0.1, SPLIT), ("split", 0.2, SPLIT),
]


def _tally(fused, rec, acc):
    truth = np.full((rec.truth.frame.max() + 1, 4), np.nan)
    truth[rec.truth.frame] = rec.truth.state
    ok = fused.success
    err = fused.state - truth[fused.frame]
    pos = np.hypot(err[:, 0], err[:, 1])
    acc["se"] += float(np.sum(pos[ok] ** 2))
    acc["nees"].append(np.einsum("ki,kij,kj->k", err[ok], np.linalg.inv(fused.covariance[ok]),
                                 err[ok]))
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
        runs = [("clean", 0.0, rec)] + [(k, p, ghost_centroids(rec, k, p, seed=seed + 100))
                                        for k, p, _ in CASES]
        for k, p, data in runs:
            acc = out.setdefault((k, p), {"se": 0.0, "nees": [], "ghost_frames": 0, "frames": 0})
            _tally(fuse_recording(data, noise=CENTROID_NOISE, robust="gate", progress=False),
                   rec, acc)
    return out


def _rmse(acc):
    return np.sqrt(acc["se"] / sum(n.size for n in acc["nees"]))


@pytest.mark.slow
@pytest.mark.parametrize("kind, p", [
    pytest.param(k, p, marks=[pytest.mark.xfail(strict=True, reason=why)] if why else [])
    for k, p, why in CASES])
def test_robust_fusion_holds_against_the_ghost_model(results, kind, p):
    """Measured (seeds 10-11, 1,200 frames): clean 0.0529 m, NEES 4.04; near_range 1.15x /
    1.34x; uniform 1.14x / 1.28x, NEES 4.05 / 3.98; the xfails quote theirs."""
    acc, clean = results[(kind, p)], results[("clean", 0.0)]
    assert _rmse(acc) <= FACTOR[p] * _rmse(clean), (_rmse(acc), _rmse(clean))
    n = np.concatenate(acc["nees"])
    lo, hi = chi2.ppf([0.025, 0.975], 4 * n.size) / n.size
    assert lo < n.mean() < hi, (n.mean(), lo, hi)
    assert acc["ghost_frames"] <= 0.02 * acc["frames"], acc["ghost_frames"]
