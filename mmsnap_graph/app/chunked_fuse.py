"""Fusing a recording file window by window (``mmsnap fuse``): an hour of 10
nodes in under 500 MB.

:func:`fuse_file` reads the detections of ``window_frames`` frames at a time
(:func:`mmsnap_graph.io.chunks.open_detection_windows`), fuses each window
with :func:`mmsnap_graph.fusion.recording.sequence.fuse_recording` and appends its rows
to the ``/fused`` group being written (:func:`mmsnap_graph.io.chunks.fused_writer`):
memory holds one window, never the whole recording nor its whole
``/fused``. Association and fusion are per frame, so the result equals
``fuse_recording`` on the whole recording, row for row; the detection
indices are those of the file's rows. The motion check of robust fusion
(:mod:`mmsnap_graph.fusion.recording.motion_check`) looks at neighbouring frames: each
window is read and fused with :data:`~mmsnap_graph.fusion.recording.motion_check.MOTION_CONTEXT_FRAMES`
frames of context on each side and keeps the rows of its own frames.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping

import numpy as np

from .._validation import check_count
from ..errors import ValidationError
from ..data.noise import MeasurementNoise
from ..fusion.config import DEFAULT_CONFIG, CoverageCheck, FusionConfig
from ..fusion.options import NetworkCalibration
from ..fusion.recording.consistency import ConsistencyMonitor, ConsistencyReport
from ..fusion.recording.coverage import declared_reach_m
from ..fusion.recording.pipeline import screen_rows
from ..fusion.recording.room import RoomReport
from ..fusion.recording.sequence import check_calibration, fuse_recording_rows
from ..fusion.recording.timing import split_offset
from ..io.chunks import open_detection_windows, fused_writer
from ..io.hdf5 import open_recording_file, recording_metadata
from ..tracking.person_ids import PersonIds

__all__ = ["DEFAULT_WINDOW_FRAMES", "ChunkedFuseSummary", "fuse_file"]

#: Frames per window: 2,000 frames (5 min at 150 ms) of 10 nodes are a few MB.
DEFAULT_WINDOW_FRAMES = 2000


@dataclass(frozen=True)
class ChunkedFuseSummary:
    """What :func:`fuse_file` wrote: the file, the ``/fused`` rows (fused
    targets), how many succeeded, the frames with a target, the windows
    fused (those with a detection)."""

    path: Path
    n_rows: int
    n_success: int
    n_frames: int
    n_windows: int
    mode: str
    covariance_method: str
    solver: str
    #: Rows flagged by the room-frame checks (outside the bounds, duplicates).
    room: RoomReport = RoomReport()
    #: The covariances' self-check from the data alone
    #: (:mod:`~mmsnap_graph.fusion.recording.consistency`); stored as the
    #: ``consistency`` attribute (JSON) of ``/fused``.
    consistency: ConsistencyReport | None = None


def _progress(total: int, progress: bool | None):
    import sys

    from tqdm.auto import tqdm  # here: only a run with a progress bar needs it

    show = sys.stderr.isatty() if progress is None else bool(progress)
    return tqdm(total=total, desc="fuse (windows)", unit="window", disable=not show, leave=False)


def _global_rows(fused, rows: Mapping[str, np.ndarray], names):
    """``fused`` with its detection indices taken to the file's rows."""
    idx = fused.detection_index.copy()
    for n, name in enumerate(names):
        seen = idx[:, n] >= 0
        if np.any(seen):
            idx[seen, n] = rows[name][idx[seen, n]]
    return dataclasses.replace(fused, detection_index=idx)


#: The per-row fields of a FusedSequence (those a window keeps of its context).
_ROW_FIELDS = ("frame", "target", "label", "detection_index", "observed", "state", "covariance",
               "laplace_covariance", "success", "status", "message", "iterations", "final_cost",
               "degeneracy", "rejected", "time_s", "information", "information_vector",
               "track_id")


def _own_rows(fused, start: int, stop: int):
    """``fused`` without the rows of the context frames (outside ``[start, stop)``)."""
    keep = (fused.frame >= start) & (fused.frame < stop)
    if keep.all():
        return fused
    return dataclasses.replace(fused, **{k: getattr(fused, k)[keep] for k in _ROW_FIELDS
                                         if getattr(fused, k) is not None})


def fuse_file(path: str | os.PathLike, config: FusionConfig = DEFAULT_CONFIG, *,
              output: str | os.PathLike | None = None,
              calibration: NetworkCalibration | None = None,
              noise: MeasurementNoise | Mapping[str, MeasurementNoise] = MeasurementNoise(),
              window_frames: int = DEFAULT_WINDOW_FRAMES,
              progress: bool | None = None) -> ChunkedFuseSummary:
    """Fuse every target in every frame of the recording file at ``path``
    window by window and store the ``/fused`` group (in ``path``, or in a
    copy of it at ``output``), atomically: the windowed driver of the one
    pipeline (:mod:`mmsnap_graph.fusion.recording.pipeline`).

    config : the :class:`~mmsnap_graph.fusion.config.FusionConfig` (as
        :func:`~mmsnap_graph.fusion.recording.sequence.fuse_recording`).
    calibration : the network's calibration (a
        :class:`~mmsnap_graph.fusion.options.NetworkCalibration`: poses,
        their covariances, clock and range offsets; default: the file's poses).
    noise : the measurement noise (one, or a mapping holding every node).
    window_frames : frames read and fused at a time; each window is read with
        ``config.context_frames`` frames of context on each side (the
        checks' look-around) and keeps its own rows, so the rows equal
        ``fuse_recording``'s, except that the learned walls are learned in
        each window (its own frames).
    progress : a tqdm bar over windows (default: when stderr is a terminal).

    Returns a :class:`ChunkedFuseSummary`. Raises what ``fuse_recording``
    raises for bad options, and :class:`~mmsnap_graph.errors.FileFormatError`
    naming the file for a missing or damaged one; the destination is then
    left as it was.
    """
    check_count(window_frames, "window_frames")
    if not isinstance(config, FusionConfig):
        raise ValidationError(f"config must be a FusionConfig, got {type(config).__name__}")
    calibration = check_calibration(calibration)
    windows = open_detection_windows(path, source=config.association.source)
    if config.check(CoverageCheck) is not None:
        # How far each node looks: declared by the file (mmsnap live's), else
        # over the whole file (a window alone would judge it by its own frames
        # and differ from the whole recording's); as coverage_reach_m.
        with open_recording_file(Path(path)) as f:
            declared = declared_reach_m(recording_metadata(f), windows.node_names)
        reach = declared if set(declared) >= set(windows.node_names) else \
            {**windows.reach_m(), **declared}
        config = config.with_coverage_reach(reach)
    # Clock offsets move each node's frames by its own whole-frame shift
    # before fusion (fusion.recording.timing.align_recording): each node's window is
    # read shifted the same way, so that a window holds the same reference
    # frames for every node.
    shifts = {str(n): split_offset(float(t), windows.frame_period_s)[0]
              for n, t in dict(calibration.time_offset_s or {}).items()}
    margin = max((abs(m) for m in shifts.values()), default=0)
    spans = list(windows.windows(int(window_frames), margin))
    fuse = functools.partial(fuse_recording_rows, config=config, calibration=calibration,
                             noise=noise, progress=False)
    if not spans:  # no detection at all: fuse_recording says so (ValidationError)
        fuse(windows.read(0, 0)[0])
    flagged = RoomReport()
    n_frames = n_windows = 0
    context = config.context_frames  # the checks' look-around
    back = config.look_back_frames   # and how far back they look (the placement check)
    person_ids = PersonIds()
    monitor = ConsistencyMonitor()
    with fused_writer(path, output=output) as writer, \
            _progress(len(spans), progress) as bar:
        for start, stop in spans:
            rec, rows = windows.read(start - back, stop + context, shifts)
            bar.update(1)
            if not any(r.size for r in rows.values()):
                continue  # a gap: no node has a detection in these frames
            fused = _own_rows(fuse(rec), start, stop)
            if len(fused) == 0:
                continue  # detections in the context frames only
            fused, report = screen_rows(fused, config)
            flagged = flagged + report
            fused = person_ids.assign(fused)  # one tracker over the windows, after the screens
            monitor.add(fused)
            writer.append(_global_rows(fused, rows, rec.node_names))
            n_frames += int(np.unique(fused.frame).size)
            n_windows += 1
        consistency = monitor.report()
        if writer.n_rows:
            writer.set_attribute("consistency", json.dumps(consistency.to_dict()))
    dst = Path(path) if output is None else Path(output)
    return ChunkedFuseSummary(path=dst, n_rows=writer.n_rows, n_success=writer.n_success,
                              n_frames=n_frames, n_windows=n_windows, mode=config.mode,
                              covariance_method=config.solve.covariance,
                              solver=config.solve.solver, room=flagged,
                              consistency=consistency)
