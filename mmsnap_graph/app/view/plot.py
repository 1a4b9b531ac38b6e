"""``mmsnap plot REC.h5``: a recording at a glance, for the user without a
viewer (matplotlib, PNG or SVG).

One map in the reference frame (S1's, metres): the room (the box of
``bounds``, as ``mmsnap fuse --bounds`` takes it), each radar with
its boresight and field of view (:func:`~.scene.field_of_view`), each radar's
points (its point cloud, else its centroids) in its colour, and the fused
people: each person id's path with its 2-sigma position ellipses
(:func:`~.scene.covariance_ellipse`, one every ``ellipse_every_s`` seconds of
the person) and its id at its first position, in the id's colour
(:func:`~.scene.id_color`, the colours of the Foxglove view). Only the
successful rows of ``/fused`` are drawn (a recording not fused: points and
radars only, said in the title).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..._atomic import atomic_path
from ...errors import ValidationError
from .scene import (ELLIPSE_SIGMA, FOV_HALF_ANGLE_RAD, boresight, covariance_ellipse,
                    detections_xy, field_of_view, id_color, node_color)

__all__ = ["PlotOptions", "plot_recording", "save_plot", "check_output", "FORMATS"]

#: Output formats, from the file's suffix.
FORMATS = ("png", "svg")
#: The smallest resolution of a PNG.
MIN_DPI = 100
#: A print's resolution: the 9 x 7.5 in figure is 5400 x 4500 pixels (97 MB).
MAX_DPI = 600


@dataclass(frozen=True, kw_only=True, slots=True)
class PlotOptions:
    """bounds : (x_min, x_max, y_min, y_max) the room's box (m), or None
    (not drawn); frames : (first, last) frames drawn, or None (all);
    source : ``"auto"`` (the point cloud when the recording has one, else
    the centroids), ``"point_cloud"`` or ``"centroids"``; ellipse_every_s :
    seconds between two ellipses of one person; fov_range_m : the fields of
    view's range (None: the farthest point drawn); dpi : of a PNG (100-600)."""

    bounds: tuple | None = None
    frames: tuple | None = None
    source: str = "auto"
    ellipse_every_s: float = 1.0
    fov_range_m: float | None = None
    dpi: int = 150

    def __post_init__(self) -> None:
        if self.bounds is not None:
            b = tuple(float(v) for v in self.bounds)
            if len(b) != 4 or not np.all(np.isfinite(b)) or not (b[0] < b[1] and b[2] < b[3]):
                raise ValidationError(f"bounds={self.bounds!r} must be x_min < x_max, "
                                      "y_min < y_max (m)")
            object.__setattr__(self, "bounds", b)
        if self.frames is not None and (len(self.frames) != 2 or self.frames[0] > self.frames[1]):
            raise ValidationError(f"frames={self.frames!r} must be (first, last), first <= last")
        if self.source not in ("auto", "point_cloud", "centroids"):
            raise ValidationError(f"source={self.source!r} must be auto, point_cloud or centroids")
        if not (np.isfinite(self.ellipse_every_s) and self.ellipse_every_s > 0):
            raise ValidationError(f"ellipse_every_s={self.ellipse_every_s!r} must be > 0 (s)")
        if self.fov_range_m is not None and not (np.isfinite(self.fov_range_m)
                                                 and self.fov_range_m > 0):
            raise ValidationError(f"fov_range_m={self.fov_range_m!r} must be > 0 (m)")
        if not (isinstance(self.dpi, int) and MIN_DPI <= self.dpi <= MAX_DPI):
            raise ValidationError(f"dpi={self.dpi!r} must be an integer within [{MIN_DPI}, "
                                  f"{MAX_DPI}] (--dpi)")


def _in_frames(frame, frames):
    frame = np.asarray(frame)
    if frames is None:
        return np.ones(frame.shape, dtype=bool)
    return (frame >= frames[0]) & (frame <= frames[1])


def _level(node, source):
    if source == "auto":
        return ("point_cloud", node.point_cloud) if node.point_cloud is not None and len(
            node.point_cloud) else ("centroids", node.centroids)
    return source, getattr(node, source)


def _draw_points(ax, rec, poses, options) -> NDArray:
    """Each node's detections; returns every point drawn (P, 2)."""
    drawn = [np.zeros((0, 2))]
    for i, name in enumerate(rec.node_names):
        kind, det = _level(rec.nodes[name], options.source)
        if det is None or not len(det):
            continue
        det = det.select(_in_frames(det.frame, options.frames))
        xy = detections_xy(det, poses[i])
        what = "points" if kind == "point_cloud" else "centroids"
        ax.scatter(xy[:, 0], xy[:, 1], s=4, color=node_color(i), alpha=0.4, linewidths=0,
                   zorder=1)
        ax.plot([], [], "o", ms=4, color=node_color(i), label=f"{name} {what} ({len(xy)})")
        drawn.append(xy)
    return np.vstack(drawn)


def _draw_radars(ax, names, poses, fov_range_m) -> None:
    for i, (name, pose) in enumerate(zip(names, poses)):
        rgb = node_color(i)
        fov = field_of_view(pose, half_angle_rad=FOV_HALF_ANGLE_RAD, range_m=fov_range_m)
        ax.fill(fov[:, 0], fov[:, 1], color=rgb, alpha=0.06, zorder=0)
        ax.plot(fov[:, 0], fov[:, 1], color=rgb, lw=0.8, ls="--", zorder=2,
                label=(f"fields of view (+-{np.degrees(FOV_HALF_ANGLE_RAD):.0f} deg, "
                       f"{fov_range_m:.1f} m)") if i == 0 else None)
        tip = boresight(pose, 0.5)
        ax.annotate("", xy=tip[1], xytext=tip[0], zorder=8,
                    arrowprops=dict(arrowstyle="-|>", color="k", lw=1.8, mutation_scale=14))
        ax.plot(*pose[:2], marker="s", ms=9, color=rgb, mec="k", zorder=8,
                label="radars (arrow: boresight)" if i == 0 else None, ls="none")
        ax.annotate(name, pose[:2], xytext=(6, -12), textcoords="offset points", fontsize=9,
                    fontweight="bold", zorder=8)


def _limits(ax, pts, poses, fused, bounds) -> None:
    """Axes around what matters: the radars, the room, the people and the
    bulk of the points (1st-99th percentile), not the fields of view's arcs."""
    parts = [poses[:, :2]]
    if len(pts):
        parts.append(np.percentile(pts, [1, 99], axis=0))
    if bounds is not None:
        parts.append(np.array([[bounds[0], bounds[2]], [bounds[1], bounds[3]]]))
    if fused is not None and np.any(fused.success):
        parts.append(np.asarray(fused.state)[np.asarray(fused.success, bool), :2])
    xy = np.vstack(parts)
    lo, hi = xy.min(axis=0) - 0.7, xy.max(axis=0) + 0.7
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])


def _draw_room(ax, bounds) -> str:
    """The room's box; returns how the room was drawn."""
    if bounds is not None:
        x0, x1, y0, y1 = bounds
        ax.plot([x0, x1, x1, x0, x0], [y0, y0, y1, y1, y0], color="k", lw=1.5, zorder=2,
                label="room (--bounds)")
        return "room: --bounds"
    return "room: not drawn (give --bounds)"


def _draw_people(ax, fused, frames, every_s) -> int:
    """Each person id's path, ellipses and label; returns the ids drawn."""
    ok = np.asarray(fused.success, bool) & _in_frames(fused.frame, frames)
    ids = fused.track_id if fused.track_id is not None else np.full(len(fused), -1)
    period = fused.frame_period_s or 1.0
    people = [i for i in np.unique(ids[ok]) if i >= 0]
    for k, tid in enumerate(people):
        rows = np.flatnonzero(ok & (ids == tid))
        rows = rows[np.argsort(fused.frame[rows], kind="stable")]
        xy, rgb = fused.state[rows, :2], id_color(tid)
        ax.plot(xy[:, 0], xy[:, 1], "-", color=rgb, lw=1.2, zorder=3, alpha=0.9)
        last_s = -np.inf
        for r in rows:
            t = fused.frame[r] * period
            if t - last_s >= every_s:
                e = covariance_ellipse(fused.state[r, :2], fused.covariance[r][:2, :2],
                                       n_sigma=ELLIPSE_SIGMA)
                ax.fill(e[:, 0], e[:, 1], facecolor=(*rgb, 0.10), edgecolor=rgb, lw=0.7,
                        zorder=3)
                last_s = t
        ax.annotate(str(tid), xy[0], xytext=(4, 4), textcoords="offset points", fontsize=8,
                    color=rgb, fontweight="bold", zorder=7)
    if fused.track_id is None:
        # Fused before person ids: every successful row, one colour.
        xy = fused.state[ok, :2]
        ax.plot(xy[:, 0], xy[:, 1], ".", ms=2, color="tab:blue", zorder=3)
    return len(people)


def plot_recording(path: str | os.PathLike, options: PlotOptions = PlotOptions()):
    """The figure of the recording at ``path`` (module docstring): a
    :class:`matplotlib.figure.Figure`."""
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    import h5py

    from ...io import read_fused, read_recording
    from ...io.fused import FUSED_GROUP
    from ...io.guard import read_guard

    rec = read_recording(path, load_cubes=False)
    with read_guard(path), h5py.File(path, "r") as f:
        has_fused = FUSED_GROUP in f
    fused = read_fused(path) if has_fused else None
    poses = (np.asarray(fused.node_poses, float) if fused is not None else
             np.array([rec.nodes[n].pose if rec.nodes[n].pose is not None else np.zeros(3)
                       for n in rec.node_names], dtype=float))
    fig = Figure(figsize=(9.0, 7.5))
    ax = fig.add_subplot(1, 1, 1)
    pts = _draw_points(ax, rec, poses, options)
    reach = np.max(np.hypot(*(pts[:, None, :] - poses[None, :, :2]).T)) if len(pts) else 4.0
    _draw_radars(ax, rec.node_names, poses, options.fov_range_m or float(reach))
    room = _draw_room(ax, options.bounds)
    handles, _ = ax.get_legend_handles_labels()
    if fused is not None:
        n = _draw_people(ax, fused, options.frames, options.ellipse_every_s)
        handles += [Line2D([], [], color="0.3", lw=1.2, label=f"fused people: path per id ({n})"),
                    Patch(facecolor=(0.3, 0.3, 0.3, 0.12), edgecolor="0.3",
                          label=f"{ELLIPSE_SIGMA:g}-sigma position ellipse, one per "
                                f"{options.ellipse_every_s:g} s")]
    _limits(ax, pts, poses, fused, options.bounds)
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlabel(f"x (m), {rec.node_names[0]}'s array axis")
    ax.set_ylabel(f"y (m), {rec.node_names[0]}'s boresight")
    ax.grid(True, lw=0.3, alpha=0.5)
    span = "all frames" if options.frames is None else \
        f"frames {options.frames[0]}-{options.frames[1]}"
    what = "fused people with their ids" if fused is not None else "not fused (mmsnap fuse)"
    ax.set_title(f"{Path(path).name}: {span}, {what}; {room}", fontsize=9)
    ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8,
              frameon=False)
    fig.tight_layout()
    return fig


def check_output(output: str | os.PathLike) -> str:
    """The format of ``output`` from its suffix (:data:`FORMATS`), or
    :class:`ValidationError`."""
    fmt = Path(output).suffix.lower().lstrip(".")
    if fmt not in FORMATS:
        raise ValidationError(f"-o {output}: the figure is written as {' or '.join(FORMATS)} "
                              "(give a .png or .svg name)")
    return fmt


def save_plot(fig, output: str | os.PathLike, *, dpi: int = 150) -> Path:
    """Write ``fig`` atomically as PNG or SVG (from the suffix of ``output``)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    fmt = check_output(output)
    output = Path(output)
    FigureCanvasAgg(fig)
    with atomic_path(output) as tmp:
        fig.savefig(tmp, dpi=dpi, format=fmt, bbox_inches="tight")
    return output
