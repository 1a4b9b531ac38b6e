"""Figures of the demo (mmsnap_graph.app.plots): the numbers behind them."""

from __future__ import annotations

from types import SimpleNamespace
import dataclasses

import numpy as np
import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import PolyCollection

from factors.models import measurement_model
from mmsnap_graph.app.plots import (
    degeneracy_grid,
    plot_degeneracy_map,
    plot_velocity_posteriors,
    save,
    velocity_posterior,
    plot_calibration_tracks,
    plot_point_clouds,
    plot_timeseries,
)
from mmsnap_graph.sim.networks import COMMON_AREAS, CONFIGURATIONS
from mmsnap_graph.sim import CLEAN, simulate_recording


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
    row = np.argmin(np.abs(d["vy"] - d["map"].state[0, 3]))
    nll, nlp = d["neg_log_likelihood"][row], d["neg_log_posterior"][row]
    assert np.ptp(nll) < 1e-6 * max(1.0, np.ptp(nlp))
    assert np.ptp(nlp) > 0.5
    # The grid covariance exists and the prior bounds the cross-line velocity.
    g = d["map"].grid_covariance[0]
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


# The figures show their uncertainty: +-2 sigma bands, colour bars, legends for
# the likelihood contours, estimates outside the axes marked at the edge, legends
# clear of the nodes, partial runs stated. Rendered with Agg (no screen).


def _render(fig):
    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    return canvas.get_renderer()


def _colorbar_labels(fig) -> list[str]:
    # matplotlib labels the axes it makes for a colour bar "<colorbar>".
    return [ax.get_ylabel() for ax in fig.axes if ax.get_label() == "<colorbar>"]


def _legend_texts(ax) -> list[str]:
    leg = ax.get_legend()
    return [] if leg is None else [t.get_text() for t in leg.get_texts()]


def _assert_legend_clear_of_nodes(fig, ax, nodes_xy):
    """The legend's box contains no node and does not overlap the axes."""
    renderer = _render(fig)
    box = ax.get_legend().get_window_extent(renderer)
    for x, y in nodes_xy:
        px, py = ax.transData.transform((x, y))
        assert not box.contains(px, py), (x, y)
    assert not box.overlaps(ax.get_window_extent(renderer))


@pytest.fixture()
def outcome():
    """A fused run of 300 frames whose ML velocity leaves the axes 7 times."""
    rng = np.random.default_rng(0)
    k = 300
    t = np.arange(k) * 0.15
    truth = np.stack([np.cos(t / 5), 4 + np.sin(t / 5), -np.sin(t / 5) / 5, np.cos(t / 5) / 5], 1)
    sd = np.array([0.05, 0.05, 0.2, 0.3])
    bayes = truth + rng.normal(size=(k, 4)) * sd
    ml = bayes.copy()
    out = np.array([3, 40, 41, 90, 120, 150, 199])
    ml[out, 2] = [9.0, -8.0, 7.5, 6.0, -7.0, 12.0, 5.0]
    cov = np.tile(np.diag(sd**2), (k, 1, 1))
    return SimpleNamespace(frame=np.arange(k), truth=truth, bayes=bayes, bayes_covariance=cov,
                           ml=ml, ekf_s1=truth, ekf_s2=truth, track_fusion=truth,
                           configuration="C", trajectory="random", calibrated_on="straight")


def test_timeseries_has_two_sigma_bands_and_marks_values_off_the_axes(outcome):
    fig = plot_timeseries(outcome)
    axes = fig.axes
    for i, ax in enumerate(axes):
        bands = [c for c in ax.collections if isinstance(c, PolyCollection)]
        assert len(bands) == 1
        ys = bands[0].get_paths()[0].vertices[:, 1]
        lo = outcome.bayes[:, i] - 2 * np.sqrt(outcome.bayes_covariance[:, i, i])
        hi = outcome.bayes[:, i] + 2 * np.sqrt(outcome.bayes_covariance[:, i, i])
        assert ys.min() == pytest.approx(lo.min()) and ys.max() == pytest.approx(hi.max())
    # vx: the seven ML excursions sit on the axes' edges, unclipped.
    ax = axes[2]
    lo, hi = ax.get_ylim()
    edge = [ln for ln in ax.lines if ln.get_marker() in ("^", "v")]
    y = np.concatenate([ln.get_ydata() for ln in edge])
    assert y.size == 7 and set(np.round(y, 9)) <= {round(lo, 9), round(hi, 9)}
    assert all(not ln.get_clip_on() for ln in edge)
    texts = _legend_texts(axes[0])
    assert "Bayesian +-2 sigma" in texts and "ML outside the axes (at the edge)" in texts
    assert "shown" not in fig.get_suptitle()


def test_timeseries_says_when_part_of_the_run_is_shown(outcome):
    fig = plot_timeseries(outcome, max_frames=200)
    assert "first 200 of 300 frames shown" in fig.get_suptitle()
    assert fig.axes[0].lines[0].get_xdata().size == 200


@pytest.fixture(scope="module")
def posterior_c():
    poses = np.stack(list(CONFIGURATIONS["C"].values()))
    truth = np.array([0.0, 3.5, 0.8, -0.3])
    z, _ = measurement_model(truth, poses)
    return velocity_posterior(poses, z, truth=truth, grid_points_per_axis=7, n_plot=31)


def test_velocity_posterior_has_a_colour_bar_and_a_legend_for_the_likelihood(posterior_c):
    fig = plot_velocity_posteriors([("C", posterior_c)])
    assert _colorbar_labels(fig) == ["posterior density / its peak"]
    ax = fig.axes[0]
    texts = _legend_texts(ax)
    for name in ("likelihood 1 sigma", "likelihood 2 sigma", "likelihood 3 sigma",
                 "grid posterior (2 sigma)", "Laplace (2 sigma)", "Bayesian (MAP)", "truth"):
        assert name in texts
    _assert_legend_clear_of_nodes(fig, ax, [posterior_c["map"].state[0, 2:]])


def test_velocity_posterior_marks_an_estimate_outside_the_axes(posterior_c):
    d = dict(posterior_c)
    d["ml"] = dataclasses.replace(d["ml"], state=np.array([[0.0, 3.5, 40.0, -0.2]]),
                                  status=np.zeros(1, dtype=np.int8))
    fig = plot_velocity_posteriors([("C", d)])
    ax = fig.axes[0]
    (mark,) = [ln for ln in ax.lines if ln.get_marker() == ">"]
    assert mark.get_xdata()[0] == pytest.approx(ax.get_xlim()[1])
    assert mark.get_ydata()[0] == pytest.approx(-0.2) and not mark.get_clip_on()
    assert any("ML: outside at (40.0, -0.2)" in t for t in _legend_texts(ax))


def _cal(true_pose):
    s1 = np.stack([np.linspace(-1, 1, 20), np.linspace(2, 4, 20)], axis=1)
    from factors.models import global_to_local

    s2 = global_to_local(s1, true_pose)
    track = lambda xy: SimpleNamespace(state=np.concatenate([xy, np.zeros_like(xy)], 1))  # noqa: E731
    return SimpleNamespace(truth_state=s1, track_s1=track(s1), track_s2=track(s2),
                           closed_form_pose=true_pose + [0.05, 0, 0.01], refined_pose=true_pose,
                           closed_form_rmse_m=0.05, refined_rmse_m=0.01, true_pose=true_pose,
                           refined_covariance=np.diag([0.02, 0.005, 0.004]) ** 2)


def test_calibration_legend_does_not_cover_the_nodes():
    true_pose = np.array(CONFIGURATIONS["B"]["S2"], dtype=float)
    fig = plot_calibration_tracks({("B", "random"): _cal(true_pose)}, ["B"], ["random"])
    _assert_legend_clear_of_nodes(fig, fig.axes[0], [(0.0, 0.0), true_pose[:2]])


def test_calibration_panel_shows_the_pose_uncertainty_and_explains_the_arrow():
    true_pose = np.array(CONFIGURATIONS["B"]["S2"], dtype=float)
    fig = plot_calibration_tracks({("B", "random"): _cal(true_pose)}, ["B"], ["random"])
    ax = fig.axes[0]
    texts = _legend_texts(ax)
    assert any("boresight" in t for t in texts)
    sigma = next(t for t in texts if t.startswith("S2 pose sigma"))
    assert "2.0 cm, 0.5 cm, 0.23 deg" in sigma and "2-sigma ellipse x" in sigma
    ellipses = [p for p in ax.patches if type(p).__name__ == "Ellipse"]
    assert len(ellipses) == 1
    k = int(sigma.rsplit("x", 1)[1].rstrip(")"))
    # 2 sigma of the larger axis (2 cm), magnified k times, as the ellipse's full width
    assert max(ellipses[0].width, ellipses[0].height) == pytest.approx(2 * 2 * 0.02 * k)
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    for x, y in [(0.0, 0.0), true_pose[:2]]:   # node labels sit inside, not clipped
        assert x0 + 0.5 < x < x1 - 0.5 and y0 + 0.5 < y < y1 - 0.5


def test_point_clouds_have_a_colour_bar_and_say_which_frame():
    rec = simulate_recording("B", "random", CLEAN, levels=("point_cloud",), n_frames=12, seed=1)
    fig = plot_point_clouds(rec, frame=5)
    assert _colorbar_labels(fig) == ["Doppler [m/s] (positive = receding)"]
    assert "frame 5" in fig.get_suptitle() and "of 12 frames" in fig.get_suptitle()
    for ax in fig.axes[:2]:
        assert len(ax.collections) == 1            # the scattered points
        _assert_legend_clear_of_nodes(fig, ax, [(0.0, 0.0)])


def test_degeneracy_map_colour_bar_and_legend_clear_of_the_nodes():
    fig = plot_degeneracy_map({"B": CONFIGURATIONS["B"]}, areas=COMMON_AREAS)
    assert len(_colorbar_labels(fig)) == 1
    ax = fig.axes[0]
    assert "walking area" in _legend_texts(ax)
    nodes = [np.asarray(p)[:2] for p in CONFIGURATIONS["B"].values()]
    _assert_legend_clear_of_nodes(fig, ax, nodes)
