#!/usr/bin/env python3
"""Draw docs/figures/frames.png, the frame conventions of docs/CONVENTIONS.md.

    python tools/make_conventions_figure.py [-o docs/figures/frames.png]

A node at pose (x_i, y_i, phi_i) with its array axis mu = (cos phi, sin phi),
its broadside (-sin phi, cos phi), its local axes, a target at range r and
angle of arrival theta (from broadside, positive toward the array axis), and
the global axes. Needs numpy and matplotlib only.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.patches import Arc, FancyArrowPatch  # noqa: E402

NODE = np.array([2.3, 0.9])
PHI = np.deg2rad(25.0)
RANGE = 3.0
THETA = np.deg2rad(32.0)


def _arrow(ax, start, end, color, width=1.8, style="-|>", **kw):
    ax.add_patch(FancyArrowPatch(start, end, arrowstyle=style, mutation_scale=16,
                                 color=color, lw=width, shrinkA=0, shrinkB=0, **kw))


def draw(path: Path) -> None:
    mu = np.array([np.cos(PHI), np.sin(PHI)])           # array axis = local x
    broadside = np.array([-np.sin(PHI), np.cos(PHI)])    # local y
    p_local = RANGE * np.array([np.sin(THETA), np.cos(THETA)])
    target = NODE + p_local[0] * mu + p_local[1] * broadside

    fig, ax = plt.subplots(figsize=(7.2, 6.0), dpi=150)
    # global axes
    _arrow(ax, (0, 0), (5.2, 0), "0.35", width=1.4)
    _arrow(ax, (0, 0), (0, 4.6), "0.35", width=1.4)
    ax.text(5.25, -0.05, "global x", color="0.25", va="top", fontsize=11)
    ax.text(0.08, 4.6, "global y", color="0.25", fontsize=11)
    ax.text(-0.1, -0.12, "origin = S1 (unless anchored)", color="0.25", ha="left", va="top", fontsize=9)

    # the node: a short antenna array along mu
    half = 0.35 * mu
    ax.plot(*np.stack([NODE - half, NODE + half]).T, color="k", lw=6, solid_capstyle="butt")
    for k in np.linspace(-1, 1, 8):
        ax.plot(*(NODE + k * half), "o", ms=3, color="w")
    ax.text(*(NODE - 0.55 * mu + [0.0, -0.32]), "node $S_i$ at $(x_i, y_i)$",
            ha="center", fontsize=10)

    # local axes: x along the array axis, y along broadside
    _arrow(ax, NODE, NODE + 2.0 * mu, "tab:blue", width=2.2)
    ax.text(*(NODE + 2.08 * mu + [0.02, -0.1]),
            "array axis $\\mu_i = (\\cos\\phi_i, \\sin\\phi_i)$\n= local $x$",
            color="tab:blue", fontsize=10, va="top")
    _arrow(ax, NODE, NODE + 2.0 * broadside, "tab:green", width=2.2)
    ax.text(*(NODE + 2.05 * broadside + [-0.25, 0.05]),
            "broadside $(-\\sin\\phi_i, \\cos\\phi_i)$\n= local $y$", color="tab:green",
            fontsize=10, ha="center", va="bottom")

    # phi: from the global x direction to the array axis, at the node
    ax.plot([NODE[0], NODE[0] + 1.3], [NODE[1], NODE[1]], ls=":", color="0.4", lw=1)
    ax.add_patch(Arc(NODE, 2.2, 2.2, theta1=0, theta2=np.rad2deg(PHI), color="tab:blue", lw=1.4))
    a = PHI / 2
    ax.text(NODE[0] + 1.2 * np.cos(a), NODE[1] + 1.2 * np.sin(a) - 0.05, "$\\phi_i$",
            color="tab:blue", fontsize=13, va="center")

    # the target, the line of sight and theta
    ax.plot(*np.stack([NODE, target]).T, color="tab:red", lw=1.4, ls="--")
    ax.plot(*target, "o", color="tab:red", ms=9)
    ax.text(*(target + [0.12, 0.05]), "target $p = (x, y)$", color="tab:red", fontsize=11)
    mid = NODE + 0.55 * (target - NODE)
    ax.text(*(mid + 0.12 * mu), "$r$", color="tab:red", fontsize=13)
    start = np.rad2deg(PHI + np.pi / 2 - THETA)
    ax.add_patch(Arc(NODE, 2.6, 2.6, theta1=start, theta2=np.rad2deg(PHI + np.pi / 2),
                     color="tab:red", lw=1.4))
    b = PHI + np.pi / 2 - THETA / 2
    ax.text(NODE[0] + 1.45 * np.cos(b), NODE[1] + 1.45 * np.sin(b), "$\\theta_i$",
            color="tab:red", fontsize=13, ha="center", va="center")

    ax.text(0.02, 0.02,
            "$\\theta_i$: from broadside, positive toward the array axis\n"
            "local target position $(r\\sin\\theta_i,\\ r\\cos\\theta_i)$;  "
            "$\\omega_i = \\pi \\sin\\theta_i$\n"
            "global $p = p_i + R(\\phi_i)\\, p_{local}$ = Pose2$(x_i, y_i, \\phi_i)$"
            ".transformFrom",
            transform=ax.transAxes, fontsize=9.5, va="bottom",
            bbox=dict(boxstyle="round", fc="white", ec="0.7"))
    ax.set_aspect("equal")
    ax.set_xlim(-0.4, 6.6)
    ax.set_ylim(-1.6, 5.0)
    ax.axis("off")
    ax.set_title("Frames: node pose $(x_i, y_i, \\phi_i)$, $\\phi_i$ = direction of the array axis",
                 fontsize=11)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, bbox_inches="tight")
    plt.close(fig)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("-o", "--output", type=Path,
                        default=Path(__file__).resolve().parents[1] / "docs" / "figures" / "frames.png")
    args = parser.parse_args(argv)
    draw(args.output)
    print(args.output)


if __name__ == "__main__":
    main()
