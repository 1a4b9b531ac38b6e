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
function the matching command calls (``process_file`` for ``mmsnap process``,
:func:`~mmsnap_graph.app.runs.calibrate_and_store` for ``mmsnap calibrate``,
:func:`~mmsnap_graph.app.runs.fuse_stored` for ``mmsnap fuse``), so a batch
run writes the same files as the commands run one by one. Running on a
multi-machine cluster: docs/SCALE.md.
"""

from __future__ import annotations

import contextlib
import inspect
import os
import socket
import sys
import time
import traceback
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import Executor
from concurrent.futures import as_completed as cf_as_completed
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from threadpoolctl import threadpool_limits  # a scikit-learn dependency

from .._validation import check_count
from ..errors import MmsnapError, ValidationError
from .runs import calibrate_and_store, calibration_json_path, fuse_stored

__all__ = ["STEPS", "WORKER_ENVIRONMENT", "RecordingSummary", "run_recording", "run_many",
           "local_client", "load_library", "dask_setup", "calibration_json_path",
           "refuse_existing_outputs"]

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
    ``n_flagged``, ``n_frames``; the fuse step's covariance self-check:
    ``self_check``, its verdict, and ``self_check_warning``, the loud sentence
    when it failed). outputs : every file written.
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


def _peak_rss_mb() -> float:
    try:
        import resource  # Unix only: imported here so that the module loads elsewhere
    except ImportError:
        return float("nan")
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / 2**20 if sys.platform == "darwin" else peak / 2**10  # bytes vs KiB


# Each step returns (counts, files written, failure message or None).
StepOutcome = tuple[dict[str, int], list[Path], str | None]


def _step_process(src: Path, dst: Path | None, options: Mapping,
                 overwrite: bool) -> StepOutcome:
    from .pipeline import process_file  # here: workers import the library, not the parser

    path, reports = process_file(src, output=dst, progress=False, **options)
    counts = {"n_nodes": len(reports),
              "n_points": sum(r.n_points for r in reports.values()),
              "n_centroids": sum(r.n_centroids for r in reports.values()),
              "n_tracks": sum(r.n_tracks for r in reports.values())}
    failed = None if any(r.level != "none" for r in reports.values()) else (
        "nothing to process: no node holds a cube, point cloud or centroids")
    return counts, [Path(path)], failed


def _step_calibrate(src: Path, dst: Path | None, options: Mapping,
                   overwrite: bool) -> StepOutcome:
    cal, written = calibrate_and_store(src, options, output=dst, overwrite=overwrite)
    counts = {"n_nodes": len(cal.node_names), "n_calibrated": len(cal.poses)}
    failed = None if cal.success else f"calibration incomplete: {cal.message}"
    return counts, [written[1], written[0]], failed


def _step_fuse(src: Path, dst: Path | None, config, overwrite: bool) -> StepOutcome:
    fused, _ = fuse_stored(src, config, output=dst, progress=False)
    counts = {"n_fused": fused.n_rows, "n_flagged": fused.n_rows - fused.n_success,
              "n_frames": fused.n_frames}
    if fused.consistency is not None:  # the covariance self-check of `mmsnap fuse`
        counts["self_check"] = fused.consistency.verdict
        if fused.consistency.warning:
            counts["self_check_warning"] = fused.consistency.warning
    return counts, [Path(fused.path)], None


_STEP_FUNCTIONS = {"process": _step_process, "calibrate": _step_calibrate, "fuse": _step_fuse}

#: Keywords a step sets itself (not accepted in its options).
_STEP_OWN = {"process": {"output", "progress"}, "calibrate": set()}


def _step_target(step: str) -> Callable:
    """The library function whose keyword arguments a step's options are."""
    if step == "process":
        from .pipeline import process_file

        return process_file
    from ..calibration import calibrate_recording

    return calibrate_recording


def _error_line(step: str, exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or "(no message)"
    return f"{step}: {type(exc).__name__}: {text}"


def run_recording(
    path: str | os.PathLike,
    steps: Sequence[str] = STEPS,
    *,
    output: str | os.PathLike | None = None,
    options: Mapping[str, Any] | None = None,
    blas_threads: int | None = 1,
    overwrite: bool = False,
) -> RecordingSummary:
    """Run ``steps`` on one recording; never raises for a bad recording.

    output : write the result here (the first writing step copies the
        recording; later steps update the copy); default: update ``path``.
    options : per step, its options (see :func:`run_many`).
    blas_threads : cap of the BLAS / OpenMP thread pools while it runs
        (None: leave them).
    overwrite : replace an existing calibration JSON (else the calibrate
        step fails naming it).
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
                arg = options.get(step, None if step == "fuse" else {})
                c, written, failed = _STEP_FUNCTIONS[step](src, dst, arg, overwrite)
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
    """Each step's options must be keywords of its library function (the
    ``fuse`` step's: one FusionConfig)."""
    from ..fusion.config import FusionConfig

    options = dict(options or {})
    for step, opts in options.items():
        if step not in steps:
            raise ValidationError(f"options given for step {step!r}, which is not in steps "
                                  f"{','.join(steps)}")
        if step == "fuse":
            if not isinstance(opts, FusionConfig):
                raise ValidationError(f"options['fuse'] must be a FusionConfig "
                                      f"(mmsnap_graph.fusion.config), got {type(opts).__name__}")
            continue
        if not isinstance(opts, Mapping):
            raise ValidationError(f"options[{step!r}] must be a mapping of keyword arguments, "
                                  f"got {type(opts).__name__}")
        target = _step_target(step)
        params = inspect.signature(target).parameters
        for key in opts:
            if key not in params or key in _STEP_OWN[step] or key in ("recording", "path"):
                raise ValidationError(f"options[{step!r}] has {key!r}, which is not an option "
                                      f"of {target.__name__}")
    return {k: v if k == "fuse" else dict(v) for k, v in options.items()}


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


def refuse_existing_outputs(paths: Sequence[str | os.PathLike], steps: Sequence[str] | str,
                            output_dir: str | os.PathLike | None = None) -> None:
    """The rule of :func:`run_many` without ``overwrite``, checked before
    anything runs: :class:`ValidationError` naming the first existing file
    the run would replace besides a recording (its copy in ``output_dir``,
    its calibration JSON)."""
    steps = _check_steps(steps)
    paths, outputs = _check_paths(paths, output_dir)
    for path, output in zip(paths, outputs):
        copy = None if output is None or os.path.realpath(output) == os.path.realpath(path) \
            else output
        replaced = [copy] if copy is not None else []
        if "calibrate" in steps:
            replaced.append(calibration_json_path(copy or path))
        for file in replaced:
            if os.path.lexists(file):
                raise ValidationError(f"{file} exists (of recording {path}); pass --overwrite "
                                      "(overwrite=True) to replace it")


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
    options: Mapping[str, Any] | None = None,
    blas_threads: int | None = 1,
    progress: bool = False,
    on_result: Callable[[RecordingSummary], None] | None = None,
    overwrite: bool = False,
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
    options : per step, its options: keyword arguments of the step's
        library function, ``process`` -> ``process_file`` (e.g.
        ``centroids_only``, ``ekf``), ``calibrate`` -> ``calibrate_recording``
        (e.g. ``matching``, ``joint``); ``fuse``: one
        :class:`~mmsnap_graph.fusion.config.FusionConfig` (default
        :data:`~mmsnap_graph.fusion.config.DEFAULT_CONFIG`, as ``mmsnap fuse``).
        They are pickled to the workers: plain values and frozen configs.
    blas_threads : BLAS / OpenMP threads per worker (None: leave them).
    progress : a tqdm bar over recordings on stderr; on_result : called
        with each summary as it arrives (in completion order).
    overwrite : replace the existing files a run writes besides the
        recordings: the copies in ``output_dir`` and the calibration JSONs
        (default: refuse them all, before anything runs, as every command
        does without ``--overwrite``).

    Returns
    -------
    list of RecordingSummary
        One per path, in the order of ``paths``. A recording that fails,
        even by killing its worker, is reported with ``success=False`` and
        its error; the others finish.

    Raises
    ------
    ValidationError
        For bad arguments only.
    """
    steps = _check_steps(steps)
    paths, outputs = _check_paths(paths, output_dir)
    options = _check_options(steps, options)
    if not overwrite:
        refuse_existing_outputs(paths, steps, output_dir)
    if executor is not None and client is not None:
        raise ValidationError("give an executor or a client, not both")
    if blas_threads is not None:
        check_count(blas_threads, "blas_threads")
    if output_dir is not None:
        Path(output_dir).mkdir(parents=True, exist_ok=True)
    args = [((p, steps), {"output": o, "options": options, "blas_threads": blas_threads,
                          "overwrite": overwrite}) for p, o in zip(paths, outputs)]
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


def load_library() -> float:
    """Import what the steps run (GTSAM, h5py, the estimators, the signal
    chain); returns the seconds it took. A worker that runs it when it
    starts spends its first recording on the recording, and the workers of
    a cluster import side by side while the cluster comes up."""
    t0 = time.perf_counter()
    from ..calibration import calibrate_recording  # noqa: F401 -- GTSAM, the calibration graphs
    from ..fusion.recording.sequence import fuse_recording  # noqa: F401 -- the fusion solvers
    from ..io.calibration import write_calibration  # noqa: F401 -- the files the steps write
    from ..io.noise import write_noise  # noqa: F401
    from .chunked_fuse import fuse_file  # noqa: F401 -- window-by-window fusion, tqdm
    from .pipeline import process_file  # noqa: F401 -- signal chain, scikit-learn, h5py
    from tqdm.auto import tqdm  # noqa: F401 -- the progress bars' module

    return time.perf_counter() - t0


def dask_setup(worker=None) -> None:
    """Dask's preload hook (``preload=["mmsnap_graph.app.batch"]``): load
    the library when a worker process starts (:func:`load_library`)."""
    load_library()


@contextlib.contextmanager
def local_client(n_workers: int, *, memory_limit: str | float | None = "auto"):
    """A Dask client on a local cluster of ``n_workers`` single-threaded
    worker processes (:data:`WORKER_ENVIRONMENT`), closed on exit. Each
    worker loads the library as it starts (:func:`dask_setup`), so the
    cluster is ready to run when this returns."""
    from distributed import Client, LocalCluster  # optional extra: mmsnap_graph[dask]

    check_count(n_workers, "n_workers")
    cluster = LocalCluster(n_workers=int(n_workers), threads_per_worker=1, processes=True,
                           dashboard_address=None, memory_limit=memory_limit,
                           env=dict(WORKER_ENVIRONMENT), preload=[__name__],
                           silence_logs=50)  # worker errors reach the summaries; keep the CLI quiet
    try:
        with Client(cluster) as client:
            yield client
    finally:
        cluster.close()
