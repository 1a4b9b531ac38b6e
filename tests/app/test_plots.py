"""Figures of the demo (mmsnap_graph.app.plots): the numbers behind them."""

from __future__ import annotations

import numpy as np
import pytest

from factors.models import measurement_model
from mmsnap_graph.app.plots import (
    degeneracy_grid,
    plot_degeneracy_map,
    plot_velocity_posteriors,
    save,
    velocity_posterior,
)
from mmsnap_graph.sim.networks import COMMON_AREAS, CONFIGURATIONS


def _value_at(x, y, cond, px, py):
    return cond[np.argmin(np.abs(y - py)), np.argmin(np.abs(x - px))]


def test_degeneracy_grid_is_one_for_orthogonal_and_huge_for_parallel_lines_of_sight():
    # B: at (0, 5) the lines of sight to S1 (0, 0) and S2 (5, 5) are orthogonal:
    # (0, 5) . (-5, 0) = 0.
    x, y, cond = degeneracy_grid(CONFIGURATIONS["B"], step_m=0.05,
                                 extent_m=(-2.0, 6.0, -1.0, 8.0))
    assert _value_at(x, y, cond, 0.0, 5.0) == pytest.approx(1.0, abs=1e-9)
    # C: on the line x = 0 between the radars, both lines of sight are parallel.
    x, y, cond = degeneracy_grid(CONFIGURATIONS["C"], step_m=0.1, extent_m=(-2.0, 2.0, 1.0, 6.0))
    assert _value_at(x, y, cond, 0.0, 3.5) > 1e6
    assert _value_at(x, y, cond, 1.5, 3.5) < 10.0
    # Outside the common field of view: NaN (behind S1).
    x, y, cond = degeneracy_grid(CONFIGURATIONS["C"], step_m=0.1, extent_m=(-2.0, 2.0, -2.0, 6.0))
    assert np.isnan(_value_at(x, y, cond, 0.0, -1.0))


def test_velocity_posterior_closes_what_the_likelihood_leaves_open():
    poses = np.stack(list(CONFIGURATIONS["C"].values()))
    truth = np.array([0.0, 3.5, 0.8, -0.3])
    z, _ = measurement_model(truth, poses)      # noise-free: the MAP sits near the truth
    d = velocity_posterior(poses, z, truth=truth, grid_points_per_axis=9, n_plot=41)
    assert d["degeneracy"] > 1e6
    # Along vx (across the line) the likelihood is flat, the posterior is not.
    row = np.argmin(np.abs(d["vy"] - d["map"].state[3]))
    nll, nlp = d["neg_log_likelihood"][row], d["neg_log_posterior"][row]
    assert np.ptp(nll) < 1e-6 * max(1.0, np.ptp(nlp))
    assert np.ptp(nlp) > 0.5
    # The grid covariance exists and the prior bounds the cross-line velocity.
    g = d["map"].grid_covariance
    assert np.all(np.isfinite(g)) and np.sqrt(g[2, 2]) < 3.5
    assert np.sqrt(g[3, 3]) < 0.5


def test_figures_render_and_save(tmp_path):
    poses = np.stack(list(CONFIGURATIONS["B"].values()))
    truth = np.array([0.5, 4.5, 0.8, 0.3])
    z, _ = measurement_model(truth, poses)
    fig = plot_velocity_posteriors([("B", velocity_posterior(poses, z, truth=truth,
                                                             grid_points_per_axis=9, n_plot=41))])
    p = save(fig, tmp_path / "sub" / "post.png")
    assert p.is_file() and p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    fig = plot_degeneracy_map({"C": CONFIGURATIONS["C"]}, areas=COMMON_AREAS)
    assert save(fig, tmp_path / "deg.png").stat().st_size > 5000
    assert not list(tmp_path.glob(".*.tmp"))
