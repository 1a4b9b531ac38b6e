"""``mmsnap demo``: the paper's experiments on simulated data, in one command.

Configurations A, B, C x straight / random trajectories, the paper's protocol
(calibrate on one trajectory, fuse the other): per-node chain, self-calibration
(closed form and refined), one-shot fusion (Bayesian and ML), track-level
fusion and the central tracker; a short stretch of raw ADC cubes through the
whole chain. Prints tables shaped like the paper's Tables II and III and
writes figures, ``report.md`` and ``results.json`` into ``--out``
(:mod:`mmsnap_graph.app.demo`, :mod:`mmsnap_graph.app.report`).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from mmsnap_graph.errors import FileFormatError, ValidationError


#: Runs at least this long (the paper's 90 s) exit 1 when a paper check does
#: not hold; shorter runs (smoke tests) only report it, unless --strict.
CHECKED_FRAMES = 600


def _list(choices):
    def parse(text: str) -> tuple[str, ...]:
        items = tuple(s.strip() for s in text.split(",") if s.strip())
        bad = [s for s in items if s not in choices]
        if not items or bad:
            raise argparse.ArgumentTypeError(f"{text!r} must be a comma-separated subset of "
                                             f"{','.join(choices)}")
        return items
    return parse


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "demo",
        help="the paper's experiments: calibration and one-shot fusion tables, figures, report",
        description="Run the paper's protocol on configurations A, B, C and both trajectories "
                    "(calibrate on one trajectory, fuse the other) on the sample data in data/ "
                    "(or simulated data when there is none), print tables like the paper's "
                    "Tables II and III and write figures and report.md into --out.")
    p.add_argument("-o", "--out", default="mmsnap_demo_out",
                   help="output folder (default %(default)s)")
    p.add_argument("--data", default=None,
                   help="folder of sample recordings config_<A|B|C>_<straight|random>.h5 "
                        "(default: ./data or the repository's data/ when present)")
    p.add_argument("--simulate", action="store_true",
                   help="simulate every run instead of reading sample recordings")
    p.add_argument("-c", "--configurations", type=_list(("A", "B", "C")), default=("A", "B", "C"),
                   help="configurations to run (default A,B,C)")
    p.add_argument("-t", "--trajectories", type=_list(("straight", "random")),
                   default=("straight", "random"),
                   help="trajectories (default straight,random: calibrate on one, fuse the other)")
    p.add_argument("-n", "--frames", type=int, default=600,
                   help="frames per run (default %(default)s = 90 s)")
    p.add_argument("-s", "--seed", type=int, default=0,
                   help="seed of the simulated runs (default %(default)s)")
    p.add_argument("--cube-frames", type=int, default=40,
                   help="frames of simulated raw ADC cubes run through the full chain "
                        "(default %(default)s; 0 = none)")
    p.add_argument("--no-figures", action="store_true", help="tables only, no figures")
    p.add_argument("--strict", action="store_true",
                   help="exit 1 when a paper check does not hold, even for runs shorter than "
                        f"{CHECKED_FRAMES} frames (always for longer runs)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def _check_samples(data_dir, config) -> None:
    """A sample path that exists but is not a file (a folder, a broken
    link) is an error, not a silent fall-back to simulation."""
    from ..demo.samples import sample_path

    for c in config.configurations:
        for t in config.trajectories:
            path = sample_path(data_dir, c, t)
            if (path.exists() or path.is_symlink()) and not path.is_file():
                raise FileFormatError(f"sample recording {path} is not a file")


def run(args: argparse.Namespace) -> int:
    # Imported here: the demo's modules pull in GTSAM and matplotlib, which
    # `mmsnap --help` and the other commands do not need.
    from ..demo import DemoConfig, find_sample_data, run_demo
    from ..report import (
        levels_text,
        qualitative_checks,
        table_cube,
        table_ii,
        table_iii_track_fusion,
        table_iii_truth,
        table_poses,
        write_figures,
        write_json,
        write_report,
    )

    t0 = time.perf_counter()
    if args.frames < 20:
        raise ValidationError(f"--frames must be >= 20, got {args.frames}")
    config = DemoConfig(configurations=tuple(args.configurations),
                        trajectories=tuple(args.trajectories), n_frames=args.frames,
                        seed=args.seed, cube_frames=args.cube_frames)
    data_dir = None if args.simulate else find_sample_data(args.data)
    if data_dir is not None:
        _check_samples(data_dir, config)
    cube_files = []
    if data_dir is not None:
        cube_files = sorted(Path(data_dir).glob("cubes_*.h5"))[:1]
    progress = (not args.no_progress) and sys.stderr.isatty()
    result = run_demo(config, data_dir=data_dir, progress=progress,
                      cube_recording_paths=cube_files)
    out = Path(args.out)
    print("mmsnap demo: the paper's protocol on simulated data")
    print(levels_text(result))
    print()
    for table in (table_ii(result), table_poses(result), table_iii_track_fusion(result),
                  table_iii_truth(result, "position"), table_iii_truth(result, "velocity")):
        print(table.text())
        print()
    if result.cube_stretches:
        print(table_cube(result).text())
        print()
    for f in result.failures:
        print(f"failure: {f}")
    print("Qualitative results of the paper:")
    checks = qualitative_checks(result)
    for c in checks:
        print(f"  [{'holds' if c.holds else 'DOES NOT HOLD'}] {c.claim}: {c.detail}")
    figures = {}
    if not args.no_figures:
        tf = time.perf_counter()
        figures = write_figures(result, out)
        result.seconds["figures"] = time.perf_counter() - tf
    wall = time.perf_counter() - t0
    cmd = "mmsnap demo " + " ".join(sys.argv[2:]) if len(sys.argv) > 1 and sys.argv[1] == "demo" \
        else "mmsnap demo"
    write_json(result, out / "results.json", extra={"wall_time_s": wall})
    report = write_report(result, out, figures, wall_time_s=wall, command=cmd.strip())
    print()
    print(f"wrote {report}, {out / 'results.json'}" + (f" and {len(figures)} figures" if figures else "")
          + f" in {wall:.1f} s")
    failed = [c.claim for c in checks if not c.holds]
    if not failed:
        return 0
    enforced = args.strict or args.frames >= CHECKED_FRAMES
    print(f"mmsnap demo: {len(failed)} paper check(s) do not hold: " + "; ".join(failed)
          + ("" if enforced else f" (not enforced for runs shorter than {CHECKED_FRAMES} "
                                 "frames; --strict enforces them)"), file=sys.stderr)
    return 1 if enforced else 0
