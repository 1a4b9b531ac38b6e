"""``mmsnap batch "GLOB"``: run the pipeline of many recordings in Dask workers.

Each recording's steps (``process``, ``calibrate``, ``fuse``: the library
functions of those commands) run in one worker; a local cluster of
single-threaded worker processes by default, or an existing
``dask.distributed`` cluster (``--scheduler``). A failed recording is listed
in the summary table and makes the exit code 1; the others finish.
Multi-machine clusters: docs/SCALE.md.
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import sys
import time
from pathlib import Path

from mmsnap_graph._atomic import atomic_path
from mmsnap_graph.app.commands.file_rules import add_overwrite
from mmsnap_graph.errors import MmsnapError, ValidationError

from .arguments import add_fusion_arguments, add_self_check_argument, fusion_config

#: Seconds to wait for a ``--scheduler`` before giving up.
CONNECT_TIMEOUT_S = 10


def max_workers() -> int:
    """The most worker processes of a local cluster: 4 per CPU (each is a
    Python process of a few hundred MB; more only queue for the CPUs)."""
    return 4 * (os.cpu_count() or 1)


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "batch",
        help="run process/calibrate/fuse on many recordings in parallel (Dask)",
        description="Run the pipeline of every recording matching the patterns, one recording "
                    "per Dask worker task: a local cluster of single-threaded worker processes "
                    "(--workers), or an existing cluster (--scheduler tcp://host:8786). Files "
                    "are updated in place (or written to --output-dir), as by the commands "
                    "process, calibrate and fuse. Exit code 1 when any recording failed.")
    p.add_argument("patterns", nargs="+", metavar="GLOB",
                   help="recordings: paths or quoted glob patterns (** recurses)")
    p.add_argument("--steps", default="process,calibrate,fuse",
                   help="comma-separated steps among process, calibrate, fuse, in that order "
                        "(default %(default)s)")
    cluster = p.add_mutually_exclusive_group()
    cluster.add_argument("--workers", type=int, default=None,
                         help="worker processes of the local cluster (default: the number of "
                              "CPUs, at most one per recording)")
    cluster.add_argument("--scheduler", default=None, metavar="ADDRESS",
                         help="address of a running dask scheduler, e.g. tcp://host:8786 (the "
                              "workers must see the recordings at the same paths)")
    p.add_argument("--output-dir", default=None,
                   help="write each result to DIR/<name> instead of updating the recordings")
    p.add_argument("--centroids-only", action="store_true",
                   help="process: only build tracks from the stored centroids")
    p.add_argument("--json-out", default=None, metavar="PATH",
                   help="also write the per-recording summaries as JSON here")
    p.add_argument("--json", action="store_true",
                   help="print the per-recording summaries as JSON to stdout instead of the "
                        "table")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_fusion_arguments(p, solvers=("vectorized", "gtsam", "scalar"))
    add_self_check_argument(p)
    add_overwrite(p, "replace existing output files: --json-out, the copies in --output-dir "
                     "and each recording's calibration JSON (default: refuse them, before "
                     "anything runs)")
    p.set_defaults(func=run)


def expand_patterns(patterns: list[str]) -> list[str]:
    """Sorted distinct files matching the patterns; a pattern matching no
    file raises :class:`ValidationError` naming it."""
    found: dict[str, str] = {}
    for pattern in patterns:
        hits = [h for h in glob.glob(pattern, recursive=True) if os.path.isfile(h)]
        if not hits:
            raise ValidationError(f"no recording matches {pattern!r}")
        for h in sorted(hits):
            found.setdefault(os.path.realpath(h), h)
    return list(found.values())


def format_summary(summaries) -> str:
    """The summary table: one row per recording, then the failed ones."""
    width = max(9, *(len(Path(s.path).name) for s in summaries))
    lines = [f"{'recording':<{width}}  {'status':<6}{'time_s':>8}{'tracks':>8}{'nodes':>7}"
             f"{'fused':>7}{'flagged':>8}  worker"]
    for s in summaries:
        c = s.counts
        cal = f"{c['n_calibrated']}/{c['n_nodes']}" if "n_calibrated" in c else "-"
        lines.append(f"{Path(s.path).name:<{width}}  {'ok' if s.success else 'FAILED':<6}"
                     f"{s.total_s:8.1f}{c.get('n_tracks', '-'):>8}{cal:>7}"
                     f"{c.get('n_fused', '-'):>7}{c.get('n_flagged', '-'):>8}  {s.worker}")
    failed = [s for s in summaries if not s.success]
    lines.append(f"{len(summaries) - len(failed)} of {len(summaries)} recording(s) ok, "
                 f"{len(failed)} failed")
    lines += [f"  FAILED {s.path}: {s.error}" for s in failed]
    return "\n".join(lines)


def _client(args: argparse.Namespace, n_recordings: int):
    """A context manager yielding the Dask client: the --scheduler's, or a
    local cluster's."""
    from mmsnap_graph.app.batch import local_client

    try:
        import distributed  # noqa: F401 -- optional extra: mmsnap_graph[dask]
    except ImportError:
        raise MmsnapError('mmsnap batch needs Dask: pip install "mmsnap_graph[dask]"') from None

    if args.scheduler is None:
        workers = args.workers or min(os.cpu_count() or 1, n_recordings)
        return local_client(workers)
    from distributed import Client  # optional extra: mmsnap_graph[dask]

    from mmsnap_graph.app.scheduler_probe import check_scheduler

    check_scheduler(args.scheduler, CONNECT_TIMEOUT_S)
    try:
        return Client(args.scheduler, timeout=CONNECT_TIMEOUT_S)
    except (OSError, TimeoutError, ValueError) as exc:
        text = " ".join(str(exc).split())
        raise ValidationError(f"--scheduler {args.scheduler}: cannot connect ({text})") from None


def _check_args(args: argparse.Namespace) -> tuple[tuple[str, ...], list[str]]:
    from mmsnap_graph.app.batch import STEPS

    steps = tuple(s.strip() for s in args.steps.split(",") if s.strip())
    if not steps or any(s not in STEPS for s in steps) or len(set(steps)) != len(steps) \
            or list(steps) != sorted(steps, key=STEPS.index):
        raise ValidationError(f"--steps must list some of {','.join(STEPS)} in that order, "
                              f"got {args.steps!r}")
    if args.workers is not None and not 1 <= args.workers <= max_workers():
        raise ValidationError(f"--workers must be between 1 and {max_workers()} (4 worker "
                              f"processes per CPU of this machine), got {args.workers}")
    if args.json_out is not None and os.path.isdir(args.json_out):
        raise ValidationError(f"--json-out {args.json_out} is a directory")
    return steps, expand_patterns(args.patterns)


def _ready(client, args) -> str:
    """The cluster's start-up in words. A local cluster's workers have loaded
    the library as they started; the workers of a ``--scheduler`` load it
    now, side by side, before the first recording."""
    from mmsnap_graph.app.batch import load_library

    if not hasattr(client, "scheduler_info"):  # a concurrent.futures executor
        return type(client).__name__
    n = len(client.scheduler_info().get("workers", {}))
    if args.scheduler is None:
        return f"{n} local worker(s), library loaded as each started"
    seconds = client.run(load_library)
    slowest = max(seconds.values(), default=0.0)
    return f"{n} worker(s) at {args.scheduler}, library loaded in {slowest:.1f} s"


def run(args: argparse.Namespace) -> int:
    from mmsnap_graph.app.batch import refuse_existing_outputs, run_many

    steps, paths = _check_args(args)
    if not args.overwrite:  # before the cluster starts
        refuse_existing_outputs(paths, steps, args.output_dir)
    options = {}
    if "process" in steps and args.centroids_only:
        options["process"] = {"centroids_only": True}
    if "fuse" in steps:
        options["fuse"] = fusion_config(args)  # mmsnap fuse's, from the same flags
    progress = not args.no_progress and sys.stderr.isatty()
    t0 = time.perf_counter()
    with _client(args, len(paths)) as client:
        ready = _ready(client, args)
        start_s = time.perf_counter() - t0
        t1 = time.perf_counter()
        summaries = run_many(paths, steps, client=client, output_dir=args.output_dir,
                             options=options, progress=progress, overwrite=args.overwrite)
        run_s = time.perf_counter() - t1
    # With --json, stdout holds the JSON alone; the words go to stderr.
    say = (lambda text: print(text, file=sys.stderr)) if args.json else print
    if args.json:
        print(json.dumps([s.to_json() for s in summaries], indent=2))
    else:
        print(format_summary(summaries))
    say(f"cluster started in {start_s:.1f} s ({ready}); recordings ran in {run_s:.1f} s")
    if not args.no_self_check:  # the fuse step's covariance self-check, loud when it failed
        for s in summaries:
            if s.counts.get("self_check_warning"):
                print(f"mmsnap batch: {s.path}: {s.counts['self_check_warning']}",
                      file=sys.stderr)
    if args.json_out:
        try:
            with atomic_path(args.json_out) as tmp:
                tmp.write_text(json.dumps([s.to_json() for s in summaries], indent=2) + "\n")
        except (OSError, MmsnapError) as exc:
            print(f"mmsnap batch: error: cannot write {args.json_out}: "
                  f"{getattr(exc, 'strerror', None) or exc}",
                  file=sys.stderr)
            return 1
        say(f"wrote {args.json_out}")
    return 0 if all(s.success for s in summaries) else 1
