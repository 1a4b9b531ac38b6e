"""The ghost generators of :mod:`mmsnap_graph.sim.real.ghosts`."""

from __future__ import annotations

import numpy as np
import pytest

from factors.models import measurement_model
from mmsnap_graph.errors import ValidationError
from mmsnap_graph.sim import CLEAN, simulate_recording
from mmsnap_graph.sim.real.ghosts import GHOST_KINDS, ghost_centroids


@pytest.fixture(scope="module")
def rec():
    return simulate_recording("B", "random", CLEAN, levels=("centroids",), n_frames=400, seed=2)


@pytest.mark.parametrize("kind", GHOST_KINDS)
def test_about_the_fraction_is_corrupted(rec, kind):
    out = ghost_centroids(rec, kind, 0.2, seed=1)
    for name in rec.node_names:
        before, after = rec.nodes[name].centroids, out.nodes[name].centroids
        ghosts = np.sum(after.target_id == -1)
        per = {"near_range": 1, "uniform": 1, "mirror": 1, "split": 2}[kind]
        # Binomial(400, 0.2) rows: 80 +- 8; mirror images out of view are dropped.
        lo = 0.5 if kind == "mirror" else 0.8
        assert lo * 80 * per < ghosts < 1.2 * 80 * per, ghosts
        assert np.all(np.diff(after.frame) >= 0)
        assert len(after) == len(before) + {"near_range": 0, "uniform": 0, "split": ghosts // 2,
                                            "mirror": ghosts}[kind]


def test_near_range_ghosts_stay_within_three_metres_of_the_truth(rec):
    out = ghost_centroids(rec, "near_range", 0.5, seed=3)
    c = out.nodes["S1"].centroids
    g = c.target_id == -1
    h, _ = measurement_model(rec.truth.state[c.frame[g]], rec.truth.node_poses["S1"])
    assert np.all(np.abs(c.range_m[g] - h[:, 0]) <= 3.0 + 4 * 0.05)


def test_split_halves_are_a_body_apart(rec):
    out = ghost_centroids(rec, "split", 1.0, seed=4)
    c = out.nodes["S1"].centroids
    th = np.arcsin(c.omega_rad / np.pi)
    xy = np.stack([c.range_m * np.sin(th), c.range_m * np.cos(th)], 1)
    for f in np.unique(c.frame)[:50]:
        a, b = xy[c.frame == f]
        assert 0.3 - 1e-6 <= np.linalg.norm(a - b) <= 0.6 + 1e-6


def test_bad_arguments():
    r = simulate_recording("C", options=CLEAN, levels=("centroids",), n_frames=5)
    with pytest.raises(ValidationError, match="kind="):
        ghost_centroids(r, "echo", 0.1)
    with pytest.raises(ValidationError, match="fraction="):
        ghost_centroids(r, "split", 1.5)
