"""Many recordings at once: each recording's pipeline in a worker process.

- :func:`run_many`: run the steps (``process``, ``calibrate``, ``fuse``) of
  many recordings on a ``concurrent.futures.Executor``, a Dask
  ``distributed.Client``, or in this process; one recording's failure is
  reported in its :class:`RecordingSummary`, the others finish;
- :func:`run_recording`: the steps of one recording (what a worker runs);
- :func:`local_client`: a local Dask cluster of single-threaded worker
  processes (the ``mmsnap batch`` default).

Workers receive paths and plain options only and build their factor graphs
themselves: GTSAM ``CustomFactor`` objects do not pickle. Each step calls the
library function of the matching command (``mmsnap process``, ``mmsnap
calibrate``, ``mmsnap fuse``), so a batch run writes the same files as the
commands run one by one. Running on a multi-machine cluster: docs/SCALE.md.
"""

from __future__ import annotations

import contextlib
import importlib
import inspect
import os
import socket
import sys
import time
import traceback
from types import SimpleNamespace
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import Executor
from concurrent.futures import as_completed as cf_as_completed
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits  # a scikit-learn dependency

from ..errors import MmsnapError, ValidationError
from .commands.fuse import (
    DEFAULT_ROBUST,
    calibration_options,
    stored_calibration,
)

__all__ = ["STEPS", "WORKER_ENVIRONMENT", "RecordingSummary", "run_recording", "run_many",
           "local_client", "calibration_json_path"]

#: The pipeline steps, in the order they run.
STEPS: tuple[str, ...] = ("process", "calibrate", "fuse")

#: Environment of every worker process: one BLAS / OpenMP thread, since a
#: worker is one process per core (threads_per_worker=1). Dask's nannies set
#: it before the worker imports numpy; :func:`run_recording` also caps the
#: BLAS pools at run time (threadpoolctl), for executors started elsewhere.
WORKER_ENVIRONMENT: dict[str, str] = {
    "OMP_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
}

# ----------------------------------------------------------------------------
# The library functions the steps call: imported in this one place, because
# some of them are moving between modules (the first module holding the name
# wins). Resolved on first use, in the worker: they import GTSAM and h5py.
# ----------------------------------------------------------------------------

_LIBRARY: dict[str, tuple[str, ...]] = {
    "process_file": ("mmsnap_graph.app.pipeline",),
    "read_recording": ("mmsnap_graph.io",),
    "calibrate_recording": ("mmsnap_graph.calibration",),
    "write_calibration": ("mmsnap_graph.io.calibration", "mmsnap_graph.calibration"),
    "write_calibration_json": ("mmsnap_graph.io.calibration", "mmsnap_graph.calibration"),
    "fuse_recording": ("mmsnap_graph.fusion.recording.sequence",),
    "write_fused": ("mmsnap_graph.io.fused", "mmsnap_graph.fusion.recording.sequence"),
    "write_noise": ("mmsnap_graph.io.noise",),
    "noise_for_fusion": ("mmsnap_graph.io.noise",),
}
_resolved: dict[str, Callable] = {}


def _library(name: str) -> Callable:
    """The library function ``name`` from the first of its modules that has it."""
    if name not in _resolved:
        for module_name in _LIBRARY[name]:
            try:
                module = importlib.import_module(module_name)
            except ModuleNotFoundError as exc:
                if exc.name is None or not module_name.startswith(exc.name):
                    raise  # the module exists but one of its imports is missing
                continue
            if hasattr(module, name):
                _resolved[name] = getattr(module, name)
                break
        else:
            raise ImportError(f"{name} is in none of {', '.join(_LIBRARY[name])}")
    return _resolved[name]


# ----------------------------------------------------------------------------
# Results
# ----------------------------------------------------------------------------


@dataclass(frozen=True, kw_only=True, slots=True)
class RecordingSummary:
    """What happened to one recording.

    path : the input recording; output : the recording written (None when no
    step wrote it). success : every requested step ran and succeeded.
    steps : the requested steps; steps_done : those that completed.
    error : one line, ``"<step>: <ExceptionType>: <message>"`` (None on
    success); detail : the traceback of an unexpected exception.
    durations_s : seconds per completed step; total_s : the whole run in the
    worker (wall clock); cpu_s : CPU seconds the worker spent on it.
    counts : what the steps produced (``n_nodes``, ``n_points``,
    ``n_centroids``, ``n_tracks``; ``n_calibrated``; ``n_fused``,
    ``n_flagged``, ``n_frames``). outputs : every file written.
    worker : ``host:pid`` of the process that ran it; peak_rss_mb : that
    process's peak resident memory so far (MiB).
    """

    path: str
    success: bool
    steps: tuple[str, ...]
    steps_done: tuple[str, ...] = ()
    error: str | None = None
    detail: str | None = None
    output: str | None = None
    outputs: tuple[str, ...] = ()
    durations_s: Mapping[str, float] = field(default_factory=dict)
    total_s: float = 0.0
    cpu_s: float = 0.0
    counts: Mapping[str, int] = field(default_factory=dict)
    worker: str = ""
    peak_rss_mb: float = float("nan")

    def to_json(self) -> dict[str, Any]:
        """A ``json.dumps``-able dict."""
        return {k: (list(v) if isinstance(v, tuple) else dict(v) if isinstance(v, Mapping) else v)
                for k, v in ((s, getattr(self, s)) for s in self.__slots__)}


# ----------------------------------------------------------------------------
# One recording (runs in a worker)
# ----------------------------------------------------------------------------


def calibration_json_path(recording: str | os.PathLike) -> Path:
    """Where the calibrate step writes the calibration JSON: next to the
    recording, ``<stem>.calibration.json`` (as ``mmsnap calibrate``)."""
    p = Path(recording)
    return p.with_name(p.stem + ".calibration.json")


def _peak_rss_mb() -> float:
    try:
        import resource  # Unix only: imported here so that the module loads elsewhere
    except ImportError:
        return float("nan")
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / 2**20 if sys.platform == "darwin" else peak / 2**10  # bytes vs KiB


# Each step returns (counts, files written, failure message or None).
StepOutcome = tuple[dict[str, int], list[Path], str | None]


def _step_process(src: Path, dst: Path | None, options: Mapping) -> StepOutcome:
    path, reports = _library("process_file")(src, output=dst, progress=False, **options)
    counts = {"n_nodes": len(reports),
              "n_points": sum(r.n_points for r in reports.values()),
              "n_centroids": sum(r.n_centroids for r in reports.values()),
              "n_tracks": sum(r.n_tracks for r in reports.values())}
    failed = None if any(r.level != "none" for r in reports.values()) else (
        "nothing to process: no node holds a cube, point cloud or centroids")
    return counts, [Path(path)], failed


def _step_calibrate(src: Path, dst: Path | None, options: Mapping) -> StepOutcome:
    rec = _library("read_recording")(src, load_cubes=False)
    cal = _library("calibrate_recording")(rec, **options)
    json_path = _library("write_calibration_json")(calibration_json_path(dst or src), cal)
    path = _library("write_calibration")(src, rec, cal, output=dst)
    if cal.noise is not None:  # as `mmsnap calibrate`: the noise from the data, /noise
        _library("write_noise")(path, cal.noise)
    counts = {"n_nodes": len(cal.node_names), "n_calibrated": len(cal.poses)}
    failed = None if cal.success else f"calibration incomplete: {cal.message}"
    return counts, [Path(path), Path(json_path)], failed


def _step_fuse(src: Path, dst: Path | None, options: Mapping) -> StepOutcome:
    rec = _library("read_recording")(src, load_cubes=False)
    options = dict(options)
    if "noise" not in options:  # as `mmsnap fuse`: /noise per node, else the paper's
        options["noise"], _ = _library("noise_for_fusion")(
            src, rec.node_names, per_node=True)
    options.setdefault("robust", DEFAULT_ROBUST)
    if "pose_covariances" not in options and "time_offset_s" not in options:
        # as `mmsnap fuse`: the stored calibration's pose covariances and clocks
        args = SimpleNamespace(calibration=None, no_pose_covariance=False,
                               no_time_offsets=False,
                               covariance=options.get("covariance", "laplace"))
        options.update(calibration_options(args, stored_calibration(args, src))[0])
    fused = _library("fuse_recording")(rec, progress=False, **options)
    path = _library("write_fused")(src, fused, output=dst)
    n_ok = int(np.count_nonzero(fused.success))
    counts = {"n_fused": len(fused), "n_flagged": len(fused) - n_ok,
              "n_frames": int(np.unique(fused.frame).size)}
    return counts, [Path(path)], None


_STEP_FUNCTIONS = {"process": _step_process, "calibrate": _step_calibrate, "fuse": _step_fuse}

#: The library function whose keyword arguments each step's options are.
_STEP_TARGETS = {"process": "process_file", "calibrate": "calibrate_recording",
                 "fuse": "fuse_recording"}
#: Keywords a step sets itself (not accepted in its options).
_STEP_OWN = {"process": {"output", "progress"}, "calibrate": set(), "fuse": {"progress"}}


def _error_line(step: str, exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or "(no message)"
    return f"{step}: {type(exc).__name__}: {text}"


def run_recording(
    path: str | os.PathLike,
    steps: Sequence[str] = STEPS,
    *,
    output: str | os.PathLike | None = None,
    options: Mapping[str, Mapping[str, Any]] | None = None,
    blas_threads: int | None = 1,
) -> RecordingSummary:
    """Run ``steps`` on one recording; never raises for a bad recording.

    output : write the result here (the first writing step copies the
        recording; later steps update the copy); default: update ``path``.
    options : per step, keyword arguments of its library function
        (``options["fuse"] = {"mode": "ml"}``; see :func:`run_many`).
    blas_threads : cap of the BLAS / OpenMP thread pools while it runs
        (None: leave them).
    The first step that raises or does not succeed stops the recording; its
    summary holds the error line (``success=False``).
    """
    steps = _check_steps(steps)
    options = options or {}
    start, start_cpu = time.perf_counter(), time.process_time()
    src = Path(path)
    dst = None if output is None or Path(output) == src else Path(output)
    done: list[str] = []
    durations: dict[str, float] = {}
    counts: dict[str, int] = {}
    outputs: list[str] = []
    error = detail = None
    limits = threadpool_limits(blas_threads) if blas_threads else contextlib.nullcontext()
    with limits:
        for step in steps:
            t0 = time.perf_counter()
            try:
                c, written, failed = _STEP_FUNCTIONS[step](src, dst, options.get(step, {}))
            except Exception as exc:  # noqa: BLE001 -- one recording must not stop the batch
                error = _error_line(step, exc)
                if not isinstance(exc, MmsnapError):
                    detail = traceback.format_exc()
                break
            durations[step] = time.perf_counter() - t0
            counts.update(c)
            outputs += [str(p) for p in written if str(p) not in outputs]
            if failed is not None:
                error = f"{step}: {failed}"
                break
            done.append(step)
            if dst is not None:
                src, dst = dst, None  # later steps update the copy in place
    wrote = [p for p in outputs if not p.endswith(".json")]
    return RecordingSummary(
        path=str(path), success=error is None, steps=tuple(steps), steps_done=tuple(done),
        error=error, detail=detail, output=wrote[-1] if wrote else None, outputs=tuple(outputs),
        durations_s=durations, total_s=time.perf_counter() - start,
        cpu_s=time.process_time() - start_cpu, counts=counts,
        worker=f"{socket.gethostname()}:{os.getpid()}", peak_rss_mb=_peak_rss_mb())


# ----------------------------------------------------------------------------
# Many recordings (runs in the caller)
# ----------------------------------------------------------------------------


def _check_steps(steps: Sequence[str] | str) -> tuple[str, ...]:
    """Steps as a tuple in pipeline order; a string is comma-separated."""
    if isinstance(steps, str):
        steps = [s.strip() for s in steps.split(",") if s.strip()]
    steps = tuple(steps)
    unknown = [s for s in steps if s not in STEPS]
    if not steps or unknown:
        raise ValidationError(f"steps must be a non-empty subset of {','.join(STEPS)}, "
                              f"got {','.join(map(str, steps)) or 'nothing'}")
    if len(set(steps)) != len(steps) or list(steps) != sorted(steps, key=STEPS.index):
        raise ValidationError(f"steps must be distinct and in the order {','.join(STEPS)}, "
                              f"got {','.join(steps)}")
    return steps


def _check_options(steps: tuple[str, ...], options: Mapping | None) -> dict[str, dict]:
    """Each step's options must be keywords of its library function."""
    options = dict(options or {})
    for step, opts in options.items():
        if step not in steps:
            raise ValidationError(f"options given for step {step!r}, which is not in steps "
                                  f"{','.join(steps)}")
        if not isinstance(opts, Mapping):
            raise ValidationError(f"options[{step!r}] must be a mapping of keyword arguments, "
                                  f"got {type(opts).__name__}")
        params = inspect.signature(_library(_STEP_TARGETS[step])).parameters
        for key in opts:
            if key not in params or key in _STEP_OWN[step] or key in ("recording", "path"):
                raise ValidationError(f"options[{step!r}] has {key!r}, which is not an option "
                                      f"of {_STEP_TARGETS[step]}")
    return {k: dict(v) for k, v in options.items()}


def _check_paths(paths, output_dir) -> tuple[list[str], list[str | None]]:
    """Input paths (distinct) and their outputs (distinct: two workers must
    never write one file)."""
    if isinstance(paths, (str, os.PathLike)):
        raise ValidationError(f"paths must be a list of recordings, got one path {str(paths)!r}")
    paths = [os.fspath(p) for p in paths]
    if not paths:
        raise ValidationError("paths is empty: no recording to run")
    seen: set[str] = set()
    for p in paths:
        key = os.path.realpath(p)
        if key in seen:
            raise ValidationError(f"recording {p!r} is listed twice")
        seen.add(key)
    if output_dir is None:
        return paths, [None] * len(paths)
    outputs = [os.path.join(os.fspath(output_dir), os.path.basename(p)) for p in paths]
    names = [os.path.basename(p) for p in paths]
    clash = sorted({n for n in names if names.count(n) > 1})
    if clash:
        raise ValidationError(f"output_dir: several recordings are named {clash[0]!r}")
    return paths, outputs


def _failed_summary(path: str, steps: tuple[str, ...], exc: BaseException) -> RecordingSummary:
    """A recording whose worker did not return (it died, or the task was lost)."""
    return RecordingSummary(path=path, success=False, steps=steps,
                            error=_error_line("worker", exc))


def _submit_all(pool, submit_args: list[tuple]) -> tuple[dict, Callable[[list], Iterator]]:
    """Submit every recording to an Executor or a Dask Client; returns
    {future: index} and the matching as_completed."""
    if hasattr(pool, "scheduler_info"):  # a dask.distributed.Client
        from distributed import as_completed as dask_as_completed  # optional extra

        futures = {pool.submit(run_recording, *a, pure=False, **kw): i
                   for i, (a, kw) in enumerate(submit_args)}
        return futures, dask_as_completed
    futures = {pool.submit(run_recording, *a, **kw): i for i, (a, kw) in enumerate(submit_args)}
    return futures, cf_as_completed


def _progress_bar(total: int, progress: bool):
    from tqdm import tqdm

    return tqdm(total=total, desc="recordings", unit="rec", disable=not progress,
                file=sys.stderr, dynamic_ncols=True)


def run_many(
    paths: Sequence[str | os.PathLike],
    steps: Sequence[str] | str = STEPS,
    *,
    executor: Executor | None = None,
    client=None,
    output_dir: str | os.PathLike | None = None,
    options: Mapping[str, Mapping[str, Any]] | None = None,
    blas_threads: int | None = 1,
    progress: bool = False,
    on_result: Callable[[RecordingSummary], None] | None = None,
) -> list[RecordingSummary]:
    """Run ``steps`` on every recording, one task per recording.

    Parameters
    ----------
    paths : the recordings (HDF5, docs/FORMAT.md), as the workers see them.
    steps : a subset of :data:`STEPS` in that order (or ``"process,fuse"``).
    executor : a ``concurrent.futures.Executor`` (e.g. a
        ``ProcessPoolExecutor``); client : a ``dask.distributed.Client``.
        At most one; neither: run here, one recording after the other.
    output_dir : write each result to ``output_dir/<name>`` (default: update
        the recordings in place, as the commands do).
    options : per step, keyword arguments of the step's library function:
        ``process`` -> ``process_file`` (e.g. ``centroids_only``, ``ekf``),
        ``calibrate`` -> ``calibrate_recording`` (e.g. ``matching``, ``joint``),
        ``fuse`` -> ``fuse_recording`` (e.g. ``mode``, ``solver``, ``noise``).
        They are pickled to the workers: plain values and frozen configs.
    blas_threads : BLAS / OpenMP threads per worker (None: leave them).
    progress : a tqdm bar over recordings on stderr; on_result : called
        with each summary as it arrives (in completion order).

    Returns one :class:`RecordingSummary` per path, in the order of
    ``paths``. A recording that fails, even by killing its worker, is
    reported with ``success=False`` and its error; the others finish.
    Raises :class:`ValidationError` for bad arguments only.
    """
    steps = _check_steps(steps)
    paths, outputs = _check_paths(paths, output_dir)
    options = _check_options(steps, options)
    if executor is not None and client is not None:
        raise ValidationError("give an executor or a client, not both")
    if blas_threads is not None and (not isinstance(blas_threads, (int, np.integer))
                                     or isinstance(blas_threads, bool) or blas_threads < 1):
        raise ValidationError(f"blas_threads must be an int >= 1 or None, got {blas_threads!r}")
    if output_dir is not None:
        Path(output_dir).mkdir(parents=True, exist_ok=True)
    args = [((p, steps), {"output": o, "options": options, "blas_threads": blas_threads})
            for p, o in zip(paths, outputs)]
    results: list[RecordingSummary | None] = [None] * len(paths)
    pool = client if client is not None else executor
    with _progress_bar(len(paths), progress) as bar:
        def record(i: int, summary: RecordingSummary) -> None:
            results[i] = summary
            bar.update(1)
            if on_result is not None:
                on_result(summary)

        if pool is None:
            for i, (a, kw) in enumerate(args):
                record(i, run_recording(*a, **kw))
            return results  # type: ignore[return-value]
        futures, as_completed = _submit_all(pool, args)
        try:
            for fut in as_completed(list(futures)):
                i = futures[fut]
                try:
                    record(i, fut.result())
                except Exception as exc:  # noqa: BLE001 -- a dead worker fails its recording only
                    record(i, _failed_summary(paths[i], steps, exc))
        finally:
            for fut in futures:
                if not fut.done():
                    fut.cancel()
    return results  # type: ignore[return-value]


@contextlib.contextmanager
def local_client(n_workers: int, *, memory_limit: str | float | None = "auto"):
    """A Dask client on a local cluster of ``n_workers`` single-threaded
    worker processes (:data:`WORKER_ENVIRONMENT`), closed on exit."""
    from distributed import Client, LocalCluster  # optional extra: mmsnap_graph[dask]

    if not isinstance(n_workers, (int, np.integer)) or isinstance(n_workers, bool) \
            or n_workers < 1:
        raise ValidationError(f"n_workers must be an int >= 1, got {n_workers!r}")
    cluster = LocalCluster(n_workers=int(n_workers), threads_per_worker=1, processes=True,
                           dashboard_address=None, memory_limit=memory_limit,
                           env=dict(WORKER_ENVIRONMENT),
                           silence_logs=50)  # worker errors reach the summaries; keep the CLI quiet
    try:
        with Client(cluster) as client:
            yield client
    finally:
        cluster.close()
