"""The README's figure: fused people with their 2-sigma ellipses over a real
recording, drawn from a recording that ``mmsnap fuse`` has written.

    python docs/figures/fused_people.py mt.h5 -o fused_people.png

``mt.h5`` is the two-person recording of ``data/real/darksz`` after the
README's tour (``import table``, ``process``, ``calibrate``, ``fuse``). Each
dot is one fused (frame, target) row that succeeded, coloured by time; every
``--every``-th frame also gets the 2-sigma ellipse of its position covariance
(the fused covariance, calibration uncertainty included). The squares are the
radars at their calibrated poses, the arrows their boresights, the dashed box
the room's bounds given to ``mmsnap fuse --bounds``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.patches import Ellipse, Rectangle  # noqa: E402

from mmsnap_graph import read_fused  # noqa: E402

#: The room box of the README's tour (``--bounds=-2,1.6,0,3.6``).
ROOM_M = (-2.0, 1.6, 0.0, 3.6)


def ellipse(mean, cov, n_sigma: float = 2.0, **style) -> Ellipse:
    """The ``n_sigma`` ellipse of a 2-D Gaussian ``(mean (2,), cov (2, 2))``."""
    w, v = np.linalg.eigh(0.5 * (cov + cov.T))
    w = np.maximum(w, 0.0)
    angle = np.degrees(np.arctan2(v[1, 1], v[0, 1]))
    return Ellipse(xy=mean, width=2 * n_sigma * np.sqrt(w[1]), height=2 * n_sigma * np.sqrt(w[0]),
                   angle=angle, fill=False, **style)


def draw(recording: Path, out: Path, *, every: int = 10, dpi: int = 120) -> tuple[int, int]:
    """Draw the figure into ``out``; returns (rows drawn, ellipses drawn)."""
    fused = read_fused(recording)
    ok = fused.success
    xy = fused.state[ok, :2]
    cov = fused.covariance[ok][:, :2, :2]
    frames = fused.frame[ok]
    times = fused.time_s[ok]
    fig, ax = plt.subplots(figsize=(6.4, 5.6), constrained_layout=True)
    x0, x1, y0, y1 = ROOM_M
    ax.add_patch(Rectangle((x0, y0), x1 - x0, y1 - y0, fill=False, ls="--", ec="0.5", lw=1.0))
    dots = ax.scatter(xy[:, 0], xy[:, 1], c=times, s=6, cmap="viridis", zorder=2)
    shown = np.flatnonzero(frames % every == 0)
    cmap = plt.get_cmap("viridis")
    span = max(float(times.max() - times.min()), 1e-9)
    for k in shown:
        colour = cmap((times[k] - times.min()) / span)
        ax.add_patch(ellipse(xy[k], cov[k], ec=colour, lw=0.8, alpha=0.9, zorder=3))
    for name, (px, py, phi) in zip(fused.node_names, fused.node_poses):
        ax.plot([px], [py], marker="s", color="k", ms=7, ls="none", zorder=4)
        # boresight = array axis + 90 degrees (docs/CONVENTIONS.md, "Frames and poses")
        ax.annotate("", xy=(px - 0.6 * np.sin(phi), py + 0.6 * np.cos(phi)), xytext=(px, py),
                    arrowprops=dict(arrowstyle="->", color="k", lw=1.2), zorder=4)
        ax.annotate(name, (px, py), textcoords="offset points", xytext=(7, -12), fontsize=9)
    from matplotlib.lines import Line2D

    handles = [Line2D([], [], marker="o", ls="none", color=cmap(0.5), ms=4,
                      label="fused position (colour: time)"),
               Ellipse((0, 0), 1, 1, fill=False, ec=cmap(0.5), label=f"2-sigma, every {every}th frame"),
               Line2D([], [], marker="s", ls="none", color="k", ms=6,
                      label="radar (calibrated pose)"),
               Line2D([], [], color="k", lw=1.2, label="boresight"),
               Rectangle((0, 0), 1, 1, fill=False, ls="--", ec="0.5", label="room (--bounds)")]
    ax.legend(handles=handles, loc="lower left", fontsize=7, framealpha=0.9)
    fig.colorbar(dots, ax=ax, label="time (s)", shrink=0.8)
    ax.set_aspect("equal")
    ax.set_xlim(x0 - 0.4, x1 + 0.6)
    ax.set_ylim(y0 - 0.5, y1 + 0.4)
    ax.set_xlabel("x (m), S1's frame")
    ax.set_ylabel("y (m)")
    ax.set_title(f"Two people, two IWR1843 radars: {len(xy)} fused rows\n"
                 f"2-sigma position ellipses every {every}th frame", fontsize=10)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=dpi)
    plt.close(fig)
    return len(xy), len(shown)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("recording", type=Path, help="a recording with /fused (mmsnap fuse)")
    parser.add_argument("-o", "--output", type=Path, default=Path("fused_people.png"))
    parser.add_argument("--every", type=int, default=10, help="an ellipse every N frames")
    parser.add_argument("--dpi", type=int, default=120)
    args = parser.parse_args(argv)
    rows, ellipses = draw(args.recording, args.output, every=args.every, dpi=args.dpi)
    print(f"wrote {args.output}: {rows} fused rows, {ellipses} ellipses")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
