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
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping

import numpy as np

from .._validation import check_count
from ..errors import ValidationError
from ..fusion.recording.motion_check import MOTION_CONTEXT_FRAMES
from ..fusion.options import DEFAULT_OPTIONS, FusionOptions, NetworkCalibration
from ..fusion.recording.room import RoomReport, screen_room
from ..fusion.recording.sequence import fuse_recording
from ..fusion.recording.timing import split_offset
from ..io.chunks import open_detection_windows, fused_writer
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


def _progress(total: int, progress: bool | None):
    import sys

    from tqdm.auto import tqdm  # here: only a run with a progress bar needs it

    show = sys.stderr.isatty() if progress is None else bool(progress)
    return tqdm(total=total, desc="fuse (windows)", unit="window", disable=not show, leave=False)


def _motion_checked(options) -> bool:
    """Whether ``fuse_recording`` runs the motion check with these options."""
    check = options.get("options", DEFAULT_OPTIONS).motion_check
    return bool(options.get("robust") is not None if check is None else check)


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


def fuse_file(path: str | os.PathLike, *, output: str | os.PathLike | None = None,
              calibration: NetworkCalibration | None = None,
              window_frames: int = DEFAULT_WINDOW_FRAMES, progress: bool | None = None,
              **options) -> ChunkedFuseSummary:
    """Fuse every target in every frame of the recording file at ``path``
    window by window and store the ``/fused`` group (in ``path``, or in a
    copy of it at ``output``), atomically.

    calibration : the network's calibration (a
        :class:`~mmsnap_graph.fusion.options.NetworkCalibration`: poses,
        their covariances, clock and range offsets; default: the file's poses).
    window_frames : frames read and fused at a time.
    progress : a tqdm bar over frames (default: when stderr is a terminal).
    options : keyword arguments of
        :func:`~mmsnap_graph.fusion.recording.sequence.fuse_recording` (``mode``,
        ``noise``, ``prior``, ``robust``, ``options`` (a
        :class:`~mmsnap_graph.fusion.options.FusionOptions`: ``covariance``,
        ``solver``, ``gate_probability``, ``source``, ...), with its defaults; and the
        room-frame checks of
        :func:`~mmsnap_graph.fusion.recording.room.screen_room`:
        ``bounds``, ``static_bounds``, ``in_front`` and ``body_m`` (each
        None or False, the default: off; ``mmsnap fuse`` checks one target per
        :data:`~mmsnap_graph.fusion.recording.room.DEFAULT_BODY_M`), and
        ``walls`` (the learned walls, default on; learned in each window).

    Returns a :class:`ChunkedFuseSummary`. Raises what ``fuse_recording``
    raises for bad options, and :class:`~mmsnap_graph.errors.FileFormatError`
    naming the file for a missing or damaged one; the destination is then
    left as it was.
    """
    check_count(window_frames, "window_frames")
    if "progress" in options or "recording" in options:
        raise ValidationError("fuse_file takes the file, not a recording; progress is its own")
    room = dict(bounds=options.pop("bounds", None), static_bounds=options.pop("static_bounds", None),
                in_front=options.pop("in_front", False), walls=options.pop("walls", True),
                body_m=options.pop("body_m", None))
    flagged = RoomReport()
    calibration = NetworkCalibration() if calibration is None else calibration
    if not isinstance(calibration, NetworkCalibration):
        raise ValidationError(f"calibration must be a NetworkCalibration, got "
                              f"{type(calibration).__name__}")
    fusion = options.get("options", DEFAULT_OPTIONS)
    if not isinstance(fusion, FusionOptions):
        raise ValidationError(f"options must be a FusionOptions, got {type(fusion).__name__}")
    windows = open_detection_windows(path, source=fusion.source)
    if fusion.coverage_check and fusion.coverage_reach_m is None:
        # How far each node looks, over the whole file (a window alone would
        # judge it by its own frames and differ from the whole recording's).
        fusion = dataclasses.replace(fusion, coverage_reach_m=windows.reach_m())
        options = {**options, "options": fusion}
    # Clock offsets move each node's frames by its own whole-frame shift
    # before fusion (fusion.recording.timing.align_recording): each node's window is
    # read shifted the same way, so that a window holds the same reference
    # frames for every node.
    shifts = {str(n): split_offset(float(t), windows.frame_period_s)[0]
              for n, t in dict(calibration.time_offset_s or {}).items()}
    margin = max((abs(m) for m in shifts.values()), default=0)
    spans = list(windows.windows(int(window_frames), margin))
    if not spans:  # no detection at all: fuse_recording says so (ValidationError)
        fuse_recording(windows.read(0, 0)[0], calibration=calibration, progress=False,
                       **options)
    n_frames = n_windows = 0
    person_ids = PersonIds()
    with fused_writer(path, output=output) as writer, \
            _progress(len(spans), progress) as bar:
        # Context frames around each window when rows are checked against
        # their neighbours' motion (the check reaches this far).
        context = MOTION_CONTEXT_FRAMES if _motion_checked(options) else 0
        for start, stop in spans:
            rec, rows = windows.read(start - context, stop + context, shifts)
            bar.update(1)
            if not any(r.size for r in rows.values()):
                continue  # a gap: no node has a detection in these frames
            fused = fuse_recording(rec, calibration=calibration, progress=False, **options)
            fused = _own_rows(fused, start, stop)
            if len(fused) == 0:
                continue  # detections in the context frames only
            fused, report = screen_room(fused, **room)
            flagged = flagged + report
            fused = person_ids.assign(fused)  # one tracker over the windows, after the screens
            writer.append(_global_rows(fused, rows, rec.node_names))
            n_frames += int(np.unique(fused.frame).size)
            n_windows += 1
    dst = Path(path) if output is None else Path(output)
    return ChunkedFuseSummary(path=dst, n_rows=writer.n_rows, n_success=writer.n_success,
                              n_frames=n_frames, n_windows=n_windows,
                              mode=options.get("mode", "map"),
                              covariance_method=fusion.covariance, solver=fusion.solver,
                              room=flagged)
