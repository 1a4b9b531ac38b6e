"""The figure of "Why the covariances are honest": the distribution of the
fused rows' NEES against the chi-square distribution an honest covariance
gives, for recordings that ``mmsnap fuse`` wrote and that carry the truth
(``mmsnap simulate``).

    python docs/figures/nees.py sim/clean.h5 sim/paper.h5 sim/half.h5 \
        --label "noise from the data" --label "the paper's sigmas" \
        --label "half the estimated sigmas" -o sim/nees.png

Each curve is the empirical distribution function of ``e^T P^-1 e`` over
the rows that succeeded (``e`` the 4-D state error against the nearest true
target of the frame, ``P`` the reported covariance); the black curve is the
chi-square distribution of 4 degrees of freedom. A curve left of it reports
covariances too large (inflated), one right of it too small (over-confident).
It prints each recording's mean NEES with the 95 % band of that mean, its
median, and the fraction of rows beyond chi-square's 99 % point.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from scipy.stats import chi2  # noqa: E402

from mmsnap_graph import read_fused, read_recording  # noqa: E402
from mmsnap_graph.evaluation import chi2_mean_interval, nees, truth_reference  # noqa: E402


def row_nees(path: Path) -> np.ndarray:
    """(K,) NEES of the succeeded fused rows of one recording."""
    fused = read_fused(path)
    truth = read_recording(path).truth
    ok = np.asarray(fused.success, dtype=bool)
    ref, _ = truth_reference(fused.frame[ok], fused.state[ok, :2], truth.frame,
                             truth.target_id, truth.state)
    keep = np.all(np.isfinite(ref), axis=1)
    return nees((fused.state[ok] - ref)[keep], np.asarray(fused.covariance)[ok][keep])


def draw(paths: list[Path], labels: list[str], out: Path, *, dpi: int = 120) -> list[str]:
    """Draw the figure into ``out``; returns one line per recording."""
    fig, ax = plt.subplots(figsize=(6.0, 4.0), constrained_layout=True)
    grid = np.linspace(0.0, 20.0, 400)
    ax.plot(grid, chi2.cdf(grid, 4), "k-", lw=2, label="chi-square, 4 dof (honest): mean 4")
    lines = []
    q99 = chi2.ppf(0.99, 4)
    for path, label in zip(paths, labels):
        values = np.sort(row_nees(path))
        lo, hi = chi2_mean_interval(4, values.size)
        ax.step(values, np.arange(1, values.size + 1) / values.size, where="post",
                label=f"{label}: mean {values.mean():.2f} ({values.size} rows; "
                      f"honest 95%: {lo:.2f}-{hi:.2f})")
        lines.append(f"{label}: mean NEES {values.mean():.2f} over {values.size} rows, "
                     f"95% band of the mean ({lo:.2f}, {hi:.2f}); median {np.median(values):.2f} "
                     f"(chi-square {chi2.median(4):.2f}); {100 * np.mean(values > q99):.1f}% "
                     f"beyond chi-square's 99% point {q99:.2f}")
    ax.set(xlim=(0, 20), ylim=(0, 1), xlabel="NEES of a fused row (x, y, vx, vy)",
           ylabel="fraction of rows at most", title="Reported covariance against the actual error")
    ax.legend(loc="lower right", fontsize=8)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=dpi)
    plt.close(fig)
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("recordings", type=Path, nargs="+",
                        help="recordings with /fused and /truth")
    parser.add_argument("--label", action="append", default=None,
                        help="one per recording, in order (default: the file names)")
    parser.add_argument("-o", "--output", type=Path, default=Path("nees.png"))
    args = parser.parse_args(argv)
    labels = args.label or [p.name for p in args.recordings]
    if len(labels) != len(args.recordings):
        parser.error("give one --label per recording")
    for line in draw(args.recordings, labels, args.output):
        print(line)
    print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
