"""Figures of the demo and the notebooks, like the paper's (matplotlib).

Every function builds a :class:`matplotlib.figure.Figure` with the
object-oriented API (no pyplot state, no backend switch: it renders with Agg
when saved and displays inline in a notebook) and returns it; ``save`` writes
it atomically. Degrees appear only here (axis labels), the library speaks
radians.

The figures show their uncertainty: +-2 sigma bands and ellipses, colour bars
on every colour scale, legends for contour lines; an estimate outside the
axes is marked at the edge (a triangle pointing out), legends sit outside
the axes (they never cover nodes or data), and a figure of part of a run says
so in its title.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Ellipse, Rectangle
from numpy.typing import ArrayLike, NDArray

from factors.models import detection_to_local, local_to_global

from .._atomic import atomic_path
from ..data.noise import GaussianPrior, MeasurementNoise
# The degeneracy names move with the fusion redesign; imported here only.
from ..fusion.degeneracy import velocity_degeneracy
from ..fusion.grid import neg_log_posterior
from ..fusion.options import FusionOptions
from ..data.results import DEGENERACY_THRESHOLD
from ..fusion.frame_problem import FrameProblem
from ..fusion.solve import solve
from ..sim.networks import in_common_field_of_view

__all__ = [
    "save",
    "draw_nodes",
    "plot_calibration_tracks",
    "plot_timeseries",
    "plot_point_clouds",
    "velocity_posterior",
    "plot_velocity_posteriors",
    "degeneracy_grid",
    "plot_degeneracy_map",
]

_COLORS = {"truth": "0.35", "bayes": "tab:blue", "ml": "tab:red", "tlf": "tab:green",
           "central": "tab:purple", "s1": "tab:cyan", "s2": "tab:orange"}


def save(fig: Figure, path: str | os.PathLike, *, dpi: int = 110) -> Path:
    """Write ``fig`` as PNG, atomically (:func:`mmsnap_graph._atomic.atomic_path`);
    the folder is created when missing."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    FigureCanvasAgg(fig)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")
    return path


def draw_nodes(ax, poses: Mapping[str, ArrayLike], *, color: str = "k", label: bool = True,
               arrow_m: float = 0.8, marker: str = "s") -> None:
    """Nodes as squares with an arrow along their broadside ``(-sin phi, cos phi)``."""
    for name, pose in poses.items():
        x, y, phi = np.asarray(pose, dtype=float)
        ax.plot([x], [y], marker=marker, color=color, ms=7, ls="none")
        ax.annotate("", xy=(x - arrow_m * np.sin(phi), y + arrow_m * np.cos(phi)), xytext=(x, y),
                    arrowprops=dict(arrowstyle="->", color=color, lw=1.2))
        if label:
            ax.annotate(name, (x, y), textcoords="offset points", xytext=(6, -10), fontsize=8,
                        color=color)


def _cov_ellipse(ax, mean: NDArray, cov: NDArray, n_sigma: float = 2.0, **kw) -> None:
    w, v = np.linalg.eigh(0.5 * (cov + cov.T))
    w = np.maximum(w, 0.0)
    angle = np.degrees(np.arctan2(v[1, 1], v[0, 1]))
    ax.add_patch(Ellipse(xy=mean, width=2 * n_sigma * np.sqrt(w[1]),
                         height=2 * n_sigma * np.sqrt(w[0]), angle=angle, fill=False, **kw))


def _legend_outside(ax, handles=None, *, ncol: int = 2, fontsize: int = 7):
    """A legend below the axes (outside them: it covers no node, track or
    estimate); constrained layout makes room for it."""
    kw = {} if handles is None else {"handles": handles}
    return ax.legend(fontsize=fontsize, loc="upper center", bbox_to_anchor=(0.5, -0.16),
                     ncol=ncol, frameon=False, **kw)


def _mark_outside(ax, x: ArrayLike, y: ArrayLike, *, color: str, label: str | None = None,
                  axis: str = "y") -> int:
    """Values of ``y`` beyond the axes' limits (along ``axis``), drawn at the
    edge as triangles pointing out (not clipped). Returns how many."""
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    lo, hi = ax.get_ylim() if axis == "y" else ax.get_xlim()
    n = 0
    for side, mask, edge, marker in (("above", y > hi, hi, "^" if axis == "y" else ">"),
                                     ("below", y < lo, lo, "v" if axis == "y" else "<")):
        if not np.any(mask):
            continue
        pos = (x[mask], np.full(int(mask.sum()), edge))
        ax.plot(*(pos if axis == "y" else pos[::-1]), ls="none", marker=marker, ms=5,
                color=color, clip_on=False, label=label if n == 0 else None)
        n += int(mask.sum())
    return n


# ----------------------------------------------------------------------------
# Tracks overlaid after calibration
# ----------------------------------------------------------------------------


def _pose_ellipse_scale(cov_xy: NDArray, *, visible_m: float = 0.12) -> int:
    """A round magnification (1, 2, 5, 10, 20, ...) that makes a 2-sigma
    ellipse's larger semi-axis at least ``visible_m`` on a room-sized plot."""
    semi = 2.0 * float(np.sqrt(max(np.linalg.eigvalsh(cov_xy).max(), 0.0)))
    for k in (1, 2, 5, 10, 20, 50, 100, 200, 500, 1000):
        if semi * k >= visible_m:
            return k
    return 1000


def _draw_pose_uncertainty(ax, pose: NDArray, cov: NDArray, color: str) -> str:
    """The 2-sigma ellipse of a calibrated node's position (the Pose2 body
    tangent's position block rotated into the global frame, docs/CONVENTIONS.md)
    magnified to be visible, and its heading's +-2 sigma as a wedge of two
    thin lines about the boresight arrow. Returns the legend text."""
    x, y, phi = pose
    c, s = np.cos(phi), np.sin(phi)
    rot = np.array([[c, -s], [s, c]])
    cov_xy = rot @ cov[:2, :2] @ rot.T
    k = _pose_ellipse_scale(cov_xy)
    _cov_ellipse(ax, pose[:2], cov_xy * k * k, n_sigma=2.0, ec=color, lw=1.0)
    sig = np.sqrt(np.clip(np.diagonal(cov), 0, None))
    for side in (-1, 1):
        a = phi + side * 2.0 * sig[2]
        ax.plot([x, x - 0.8 * np.sin(a)], [y, y + 0.8 * np.cos(a)], color=color, lw=0.6,
                alpha=0.7)
    return (f"S2 pose sigma {sig[0] * 100:.1f} cm, {sig[1] * 100:.1f} cm, "
            f"{np.degrees(sig[2]):.2f} deg (2-sigma ellipse x{k})")


def _fit_limits(ax, points: NDArray, margin_m: float = 0.8) -> None:
    """Axis limits holding every point with a margin (node labels not clipped)."""
    lo, hi = np.nanmin(points, axis=0) - margin_m, np.nanmax(points, axis=0) + margin_m
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])


def _calibration_panel(ax, cal) -> None:
    if cal.truth_state is not None:
        ax.plot(cal.truth_state[:, 0], cal.truth_state[:, 1], color=_COLORS["truth"],
                lw=3, alpha=0.35, label="truth")
    t1, t2 = cal.track_s1, cal.track_s2
    ax.plot(t1.state[:, 0], t1.state[:, 1], color=_COLORS["s1"], lw=0.9, label="S1 track")
    cf = local_to_global(t2.state[:, :2], cal.closed_form_pose)
    rf = local_to_global(t2.state[:, :2], cal.refined_pose)
    ax.plot(cf[:, 0], cf[:, 1], color=_COLORS["s2"], lw=0.8, ls="--",
            label=f"S2, closed form ({cal.closed_form_rmse_m:.3f} m)")
    ax.plot(rf[:, 0], rf[:, 1], color="tab:red", lw=0.8,
            label=f"S2, refined ({cal.refined_rmse_m:.3f} m)")
    draw_nodes(ax, {"S1": np.zeros(3), "S2": cal.true_pose}, color="k")
    draw_nodes(ax, {"S2'": cal.refined_pose}, color="tab:red", label=False)
    text = _draw_pose_uncertainty(ax, np.asarray(cal.refined_pose, float),
                                  np.asarray(cal.refined_covariance, float), "tab:red")
    handles, _ = ax.get_legend_handles_labels()
    handles += [Line2D([], [], color="k", marker=r"$\uparrow$", ms=9, ls="none",
                       label="node and boresight (phi: array axis)"),
                Line2D([], [], color="tab:red", lw=1.0, label=text)]
    _legend_outside(ax, handles, ncol=1)
    _fit_limits(ax, np.vstack([t1.state[:, :2], rf, np.zeros((1, 2)), cal.true_pose[None, :2],
                               cal.refined_pose[None, :2]]))


def plot_calibration_tracks(calibrations: Mapping[tuple[str, str], object],
                            configurations: Sequence[str], trajectories: Sequence[str]) -> Figure:
    """Each calibration run: S1's track, S2's track mapped into S1's frame with
    the closed-form pose and with the refined pose, and the truth (paper's
    "tracks overlaid after calibration"); the nodes with their boresight
    arrows (black: true, red: refined), the refined pose's 2-sigma position
    ellipse (magnified as its legend says) and heading wedge.
    ``calibrations`` maps ``(configuration, trajectory)`` to
    :class:`mmsnap_graph.app.demo.CalibrationOutcome`.
    """
    nr, nc = len(trajectories), len(configurations)
    fig = Figure(figsize=(4.4 * nc, 5.2 * nr), layout="constrained")
    axes = fig.subplots(nr, nc, squeeze=False)
    for i, traj in enumerate(trajectories):
        for j, conf in enumerate(configurations):
            ax = axes[i, j]
            cal = calibrations.get((conf, traj))
            ax.set_title(f"{conf}, {traj}" + ("" if cal else " (failed)"), fontsize=10)
            ax.set_aspect("equal")
            if cal is None:
                continue
            _calibration_panel(ax, cal)
            ax.set_xlabel("x [m]")
            ax.set_ylabel("y [m]")
            ax.grid(alpha=0.3)
    fig.suptitle("Tracks overlaid after self-calibration (S1 frame); track RMSE in brackets; "
                 "arrows point along each radar's boresight")
    return fig


# ----------------------------------------------------------------------------
# X / Y / Vx / Vy over time
# ----------------------------------------------------------------------------


def plot_timeseries(fusion, frame_period_s: float = 0.15, *, max_frames: int | None = None
                    ) -> Figure:
    """x, y, vx, vy over time of one fused run
    (:class:`mmsnap_graph.app.demo.FusionOutcome`): one-shot Bayesian with its
    +-2 sigma band (Laplace covariance) and ML, the two nodes' EKF tracks
    (global frame), the track-level fusion and the truth.
    Velocity axes are limited to the truth's range +-2 m/s: one-shot
    estimates beyond them (ML in a degenerate geometry) are marked at the
    edge (their RMSE is in the tables). With ``max_frames`` shorter than the
    run, the title says which part is shown."""
    n_all = fusion.frame.size
    k = n_all if max_frames is None else min(int(max_frames), n_all)
    t = fusion.frame[:k] * frame_period_s
    fig = Figure(figsize=(10, 9.0), layout="constrained")
    if k == 0:
        return fig
    axes = fig.subplots(4, 1, sharex=True)
    names = ["x [m]", "y [m]", "vx [m/s]", "vy [m/s]"]
    sd = np.sqrt(np.clip(np.diagonal(fusion.bayes_covariance[:k], axis1=1, axis2=2), 0.0, None))
    handles: dict[str, object] = {}
    for i, ax in enumerate(axes):
        ax.fill_between(t, fusion.bayes[:k, i] - 2 * sd[:, i], fusion.bayes[:k, i] + 2 * sd[:, i],
                        color=_COLORS["bayes"], alpha=0.2, lw=0, label="Bayesian +-2 sigma")
        ax.plot(t, fusion.truth[:k, i], color="k", lw=2.0, alpha=0.5, label="truth")
        ax.plot(t, fusion.ekf_s1[:k, i], color=_COLORS["s1"], lw=0.8, label="EKF S1")
        ax.plot(t, fusion.ekf_s2[:k, i], color=_COLORS["s2"], lw=0.8, label="EKF S2")
        ax.plot(t, fusion.track_fusion[:k, i], color=_COLORS["tlf"], lw=1.0, ls="--",
                label="track-level fusion")
        ax.plot(t, fusion.ml[:k, i], color=_COLORS["ml"], lw=0.6, marker=".", ms=2.5,
                label="one-shot ML")
        ax.plot(t, fusion.bayes[:k, i], color=_COLORS["bayes"], lw=0.8, marker=".", ms=2.5,
                label="one-shot Bayesian")
        ax.set_ylabel(names[i])
        ax.grid(alpha=0.3)
        if i >= 2:
            lo, hi = np.nanmin(fusion.truth[:k, i]), np.nanmax(fusion.truth[:k, i])
            ax.set_ylim(lo - 2.0, hi + 2.0)
            for key, label in (("ml", "ML"), ("bayes", "Bayesian")):
                _mark_outside(ax, t, getattr(fusion, key)[:k, i], color=_COLORS[key],
                              label=f"{label} outside the axes (at the edge)")
        for h, lab in zip(*ax.get_legend_handles_labels()):
            handles.setdefault(lab, h)
    # One legend for all panels, above them (outside the axes).
    axes[0].legend(handles=list(handles.values()), ncol=5, fontsize=7, loc="lower center",
                   bbox_to_anchor=(0.5, 1.02), frameon=False)
    axes[-1].set_xlabel("time [s]")
    part = "" if k == n_all else f"; first {k} of {n_all} frames shown"
    fig.suptitle(f"Configuration {fusion.configuration}, {fusion.trajectory} trajectory "
                 f"(calibrated on {fusion.calibrated_on}{part})")
    return fig


# ----------------------------------------------------------------------------
# Point clouds
# ----------------------------------------------------------------------------


def plot_point_clouds(recording, *, frame: int | None = None, source: str = "point_cloud"
                      ) -> Figure:
    """One frame's detections of each node in the node's own frame (x along
    the array, y broadside), coloured by Doppler (colour bar in m/s), over
    the node's whole EKF track when it has one. ``frame`` defaults to the
    middle frame of the first node's detections; the title says which frame
    of how many is shown. ``source``: ``"point_cloud"`` or ``"centroids"``.
    """
    names = [n for n in recording.node_names if getattr(recording.nodes[n], source) is not None]
    fig = Figure(figsize=(5.0 * max(1, len(names)), 4.8), layout="constrained")
    if not names:
        return fig
    first = getattr(recording.nodes[names[0]], source)
    all_frames = np.unique(np.concatenate([getattr(recording.nodes[n], source).frame
                                           for n in names]))
    if frame is None:
        frame = int(first.frame[len(first) // 2]) if len(first) else 0
    # A symmetric colour scale over the bulk of the Doppler values (a few
    # false alarms would wash it out).
    vmax = max([1.0] + [float(np.percentile(np.abs(getattr(recording.nodes[n], source)
                                                   .doppler_mps), 99))
                        for n in names if len(getattr(recording.nodes[n], source))])
    axes = fig.subplots(1, len(names), squeeze=False)[0]
    sc = None
    for ax, name in zip(axes, names):
        det = getattr(recording.nodes[name], source)
        k = det.frame == frame
        p = detection_to_local(det.range_m[k], det.omega_rad[k])
        sc = ax.scatter(p[:, 0], p[:, 1], c=det.doppler_mps[k], s=14, cmap="coolwarm",
                        vmin=-vmax, vmax=vmax, label=f"{source.replace('_', ' ')}, frame {frame}")
        tracks = recording.nodes[name].tracks
        if tracks is not None and len(tracks):
            ax.plot(tracks.state[:, 0], tracks.state[:, 1], lw=0.8, color="k", label="EKF track")
        draw_nodes(ax, {name: np.zeros(3)}, color="k")
        reach = max(2.0, float(np.max(np.abs(p), initial=0.0))) + 0.5
        ax.set_xlim(-reach, reach)
        ax.set_ylim(-0.5, reach)
        ax.set_aspect("equal")
        ax.set_title(f"{name}: its own frame ({int(k.sum())} points)", fontsize=10)
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.grid(alpha=0.3)
        _legend_outside(ax)
    cb = fig.colorbar(sc, ax=list(axes), shrink=0.85)
    cb.set_label("Doppler [m/s] (positive = receding)")
    where = (f"{int(np.searchsorted(all_frames, frame)) + 1} of {all_frames.size} frames with "
             f"detections" if frame in all_frames else
             f"no detections; {all_frames.size} frames have some")
    fig.suptitle(f"One frame of the run: frame {frame} ({where})")
    return fig


# ----------------------------------------------------------------------------
# Velocity posteriors
# ----------------------------------------------------------------------------


def velocity_posterior(node_poses: ArrayLike, measurements: ArrayLike, *,
                       truth: ArrayLike | None = None, grid_points_per_axis: int = 15,
                       n_plot: int = 161, noise=None, prior=None) -> dict:
    """One frame's velocity posterior, for :func:`plot_velocity_posteriors`.

    MAP with the grid covariance (:func:`mmsnap_graph.fusion.solve.solve`
    with GTSAM, ``covariance="grid"``), ML with its Laplace covariance, and the
    negative log posterior and log likelihood on an ``n_plot`` x ``n_plot``
    grid of ``(vx, vy)`` at the MAP position (a conditional slice).
    Returns a dict of arrays (keys: ``map``, ``ml``, ``vx``, ``vy``,
    ``neg_log_posterior``, ``neg_log_likelihood``, ``truth``, ``degeneracy``).
    """
    noise = MeasurementNoise() if noise is None else noise
    prior = GaussianPrior() if prior is None else prior
    poses = np.asarray(node_poses, dtype=float)
    z = np.asarray(measurements, dtype=float)
    grid = FusionOptions(solver="gtsam", covariance="grid",
                         grid_points_per_axis=int(grid_points_per_axis))
    res_map = solve(FrameProblem(poses=poses, measurements=z, noise=noise, prior=prior), grid)
    res_ml = solve(FrameProblem(poses=poses, measurements=z, noise=noise, prior=None),
                   FusionOptions(solver="gtsam"))
    c = res_map.state[0]
    cov = res_map.grid_covariance[0] if np.all(np.isfinite(res_map.grid_covariance)) \
        else res_map.covariance[0]
    half = np.maximum(4.0 * np.sqrt(np.diag(cov)[2:]), 1.0)
    vx = np.linspace(c[2] - half[0], c[2] + half[0], int(n_plot))
    vy = np.linspace(c[3] - half[1], c[3] + half[1], int(n_plot))
    gx, gy = np.meshgrid(vx, vy)
    states = np.empty(gx.shape + (4,))
    states[..., 0], states[..., 1] = c[0], c[1]
    states[..., 2], states[..., 3] = gx, gy
    kw = dict(node_poses=poses, measurements=z, observed=None, sigmas=noise.sigmas)
    nlp = neg_log_posterior(states, prior_mean=prior.mean, prior_sigmas=prior.sigmas, **kw)
    nll = neg_log_posterior(states, prior_mean=None, prior_sigmas=None, **kw)
    return {"map": res_map, "ml": res_ml, "vx": vx, "vy": vy, "neg_log_posterior": nlp,
            "neg_log_likelihood": nll, "truth": None if truth is None else np.asarray(truth),
            "degeneracy": float(res_map.degeneracy[0]), "node_poses": poses}


#: The likelihood's contour levels: 0.5 * chi2_2 quantiles of 1, 2, 3 sigma
#: (39%, 86%, 99% of a 2-D Gaussian), and their line styles.
_LIKELIHOOD_LEVELS = ((0.5, "-", "1 sigma"), (2.0, "--", "2 sigma"), (4.5, ":", "3 sigma"))


def _mark_point(ax, point: NDArray, label: str, **style) -> None:
    """A 2-D estimate as a marker, or, when it lies outside the axes, a
    triangle at the nearest edge pointing towards it (not clipped) whose
    label gives its value."""
    x0, x1 = ax.get_xlim()
    y0, y1 = ax.get_ylim()
    x, y = float(point[0]), float(point[1])
    if x0 <= x <= x1 and y0 <= y <= y1:
        ax.plot([x], [y], ls="none", label=label, **style)
        return
    cx, cy = min(max(x, x0), x1), min(max(y, y0), y1)
    marker = (">" if x > x1 else "<") if not x0 <= x <= x1 else ("^" if y > y1 else "v")
    style = {**style, "marker": marker, "ms": 9}
    ax.plot([cx], [cy], ls="none", clip_on=False,
            label=f"{label}: outside at ({x:.1f}, {y:.1f}), marked at the edge", **style)


def plot_velocity_posteriors(panels: Sequence[tuple[str, dict]]) -> Figure:
    """Velocity posteriors side by side: ``panels`` are ``(title, data)``
    with data from :func:`velocity_posterior`. Filled: the posterior density
    (conditional on the MAP position, colour bar relative to its peak); black
    lines: the likelihood's 1, 2, 3 sigma contours (in the legend); ellipses
    (2 sigma): the grid posterior covariance and the Laplace covariance of
    the MAP. An estimate outside the axes (ML in a degenerate geometry) is
    marked at the edge with its value."""
    fig = Figure(figsize=(5.6 * len(panels), 6.0), layout="constrained")
    axes = fig.subplots(1, len(panels), squeeze=False)[0]
    for ax, (title, d) in zip(axes, panels):
        vx, vy = d["vx"], d["vy"]
        post = np.exp(-(d["neg_log_posterior"] - d["neg_log_posterior"].min()))
        filled = ax.contourf(vx, vy, post, levels=np.linspace(0.02, 1.0, 12), cmap="Blues")
        cb = fig.colorbar(filled, ax=ax, shrink=0.9, ticks=[0.02, 0.2, 0.4, 0.6, 0.8, 1.0])
        cb.set_label("posterior density / its peak")
        dl = d["neg_log_likelihood"] - d["neg_log_likelihood"].min()
        ax.contour(vx, vy, dl, levels=[lv for lv, _, _ in _LIKELIHOOD_LEVELS], colors="k",
                   linewidths=0.8, linestyles=[ls for _, ls, _ in _LIKELIHOOD_LEVELS])
        ax.set_xlim(vx[0], vx[-1])
        ax.set_ylim(vy[0], vy[-1])
        m, ml = d["map"], d["ml"]
        if m.grid_covariance is not None and np.all(np.isfinite(m.grid_covariance)):
            _cov_ellipse(ax, m.state[0, 2:], m.grid_covariance[0, 2:, 2:], color="tab:blue",
                         lw=1.8, label="grid posterior (2 sigma)")
        _cov_ellipse(ax, m.state[0, 2:], m.covariance[0, 2:, 2:], color="tab:cyan", lw=1.0,
                     ls="--", label="Laplace (2 sigma)")
        _mark_point(ax, m.state[0, 2:], "Bayesian (MAP)", marker="o", color="tab:blue")
        if ml.success[0] and np.all(np.isfinite(ml.state)):
            _mark_point(ax, ml.state[0, 2:], "ML", marker="x", color="tab:red", ms=9, mew=2)
        if d["truth"] is not None:
            _mark_point(ax, d["truth"][2:], "truth", marker="*", color="k", ms=11)
        ax.set_xlabel("vx [m/s]")
        ax.set_ylabel("vy [m/s]")
        ax.set_title(f"{title}\ndegeneracy (cond.) {d['degeneracy']:.3g}", fontsize=10)
        handles, _ = ax.get_legend_handles_labels()
        handles += [Line2D([], [], color="k", lw=0.8, ls=ls, label=f"likelihood {name}")
                    for _, ls, name in _LIKELIHOOD_LEVELS]
        _legend_outside(ax, handles)
        ax.grid(alpha=0.3)
    fig.suptitle("Velocity posterior (filled) and likelihood (contours) of one frame")
    return fig


# ----------------------------------------------------------------------------
# Degeneracy map
# ----------------------------------------------------------------------------


def degeneracy_grid(node_poses: Mapping[str, ArrayLike], *, step_m: float = 0.1,
                    extent_m: tuple[float, float, float, float] | None = None,
                    **fov_limits) -> tuple[NDArray, NDArray, NDArray]:
    """The velocity-degeneracy indicator (condition number of the lines of
    sight's velocity information, :func:`mmsnap_graph.fusion.degeneracy.velocity_degeneracy`)
    on a grid over the nodes' common field of view.

    Returns ``x (nx,)``, ``y (ny,)`` and ``cond (ny, nx)`` (NaN outside the
    common field of view, :func:`mmsnap_graph.sim.networks.in_common_field_of_view`).
    """
    poses = {k: np.asarray(v, dtype=float) for k, v in node_poses.items()}
    xy = np.stack([p[:2] for p in poses.values()])
    if extent_m is None:
        lo, hi = xy.min(0) - 4.0, xy.max(0) + 4.0
        extent_m = (lo[0], hi[0], lo[1], hi[1] + 3.0)
    x = np.arange(extent_m[0], extent_m[1] + 1e-9, step_m)
    y = np.arange(extent_m[2], extent_m[3] + 1e-9, step_m)
    gx, gy = np.meshgrid(x, y)
    pts = np.stack([gx.ravel(), gy.ravel()], axis=1)
    states = np.concatenate([pts, np.zeros_like(pts)], axis=1)
    arr = np.stack(list(poses.values()))
    obs = np.ones((pts.shape[0], arr.shape[0]), dtype=bool)
    with np.errstate(divide="ignore", invalid="ignore"):
        cond = velocity_degeneracy(states, arr, obs).reshape(gx.shape)
    inside = in_common_field_of_view(np.stack([gx, gy], axis=-1), poses, **fov_limits)
    return x, y, np.where(inside, cond, np.nan)


def plot_degeneracy_map(networks: Mapping[str, Mapping[str, ArrayLike]], *,
                        areas: Mapping[str, object] | None = None,
                        trajectories: Mapping[str, NDArray] | None = None,
                        threshold: float | None = None) -> Figure:
    """log10 of the degeneracy indicator over each network's common field of
    view, with the nodes, the walking area and optionally a trajectory
    ``(K, >=2)`` per network; the contour marks ``threshold`` (default
    :data:`mmsnap_graph.data.results.DEGENERACY_THRESHOLD`)."""
    thr = DEGENERACY_THRESHOLD if threshold is None else float(threshold)
    fig = Figure(figsize=(4.6 * len(networks), 4.6), layout="constrained")
    axes = fig.subplots(1, len(networks), squeeze=False)[0]
    mesh = None
    for ax, (name, poses) in zip(axes, networks.items()):
        xy = np.stack([np.asarray(p, dtype=float)[:2] for p in poses.values()])
        lo, hi = xy.min(0) - 2.0, xy.max(0) + 2.0
        if areas is not None and name in areas:
            a = areas[name]
            lo = np.minimum(lo, [a.x_min_m - 3.0, a.y_min_m - 3.0])
            hi = np.maximum(hi, [a.x_max_m + 3.0, a.y_max_m + 3.0])
        x, y, cond = degeneracy_grid(poses, extent_m=(lo[0], hi[0], lo[1], hi[1]))
        val = np.log10(np.clip(cond, 1.0, 1e4))
        mesh = ax.pcolormesh(x, y, val, cmap="magma_r", vmin=0.0, vmax=3.0, shading="auto")
        if np.any(np.isfinite(cond)):
            ax.contour(x, y, np.nan_to_num(cond, nan=0.0), levels=[thr], colors="tab:cyan",
                       linewidths=1.2)
        if areas is not None and name in areas:
            a = areas[name]
            ax.add_patch(Rectangle((a.x_min_m, a.y_min_m), a.x_max_m - a.x_min_m,
                                   a.y_max_m - a.y_min_m, fill=False, ec="tab:green", lw=1.5))
        if trajectories is not None and name in trajectories:
            tr = np.asarray(trajectories[name])
            ax.plot(tr[:, 0], tr[:, 1], color="tab:blue", lw=0.6, alpha=0.8)
        draw_nodes(ax, poses, color="k")
        ax.set_aspect("equal")
        ax.set_xlim(x[0], x[-1])
        ax.set_ylim(y[0], y[-1])
        ax.set_title(f"configuration {name}", fontsize=10)
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        _legend_outside(ax, [
            Line2D([], [], color="tab:cyan", lw=1.2, label=f"condition number {thr:g}"),
            Rectangle((0, 0), 1, 1, fill=False, ec="tab:green", lw=1.5, label="walking area"),
            Line2D([], [], color="tab:blue", lw=0.6, label="trajectory")][
                :3 if trajectories is not None and name in trajectories else 2])
    if mesh is not None:
        cb = fig.colorbar(mesh, ax=list(axes), shrink=0.85)
        cb.set_label("log10 condition number of the velocity information\n"
                     "0: both components seen alike; 3: one barely seen", fontsize=8)
    fig.suptitle("Where one frame determines a walker's velocity: dark where the radars' lines "
                 f"of sight are nearly parallel\n(beyond the cyan line, condition number {thr:g}, "
                 "one velocity component is poorly determined; green: walking area; "
                 "blue: trajectory)")
    return fig
