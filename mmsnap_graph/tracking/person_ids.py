"""Person ids of fused rows: the central tracker over a recording's one-shot
estimates, as the stream runs it live.

:class:`PersonIds` steps one :class:`~mmsnap_graph.tracking.central.CentralTracker`
over the rows of a :class:`~mmsnap_graph.data.results.FusedSequence` in frame
order, and gives each successful row the id of the track it updated or
started (:attr:`CentralTracker.estimate_ids`); any other row gets -1. It takes
a whole recording at once or window after window (the tracker carries over
from one call to the next, so a file fused window by window gets the ids of
the whole recording fused at once).

Every frame from the first fused frame on is a tracker step, as in
:func:`~mmsnap_graph.tracking.central.track_fused`: a frame without a
successful row only predicts. A gap during which no track is alive is
skipped (the tracker then holds nothing but its next id, so skipping changes
nothing), which bounds the work of a long gap by ``max_misses`` steps.

Each driver of the fusion pipeline runs this step last: in memory
(``fuse_recording``), window by window over a file (``fuse_file``, one
:class:`PersonIds` for the whole file, after the room checks), and frame by
frame (:meth:`PersonIds.frame_ids`, the step the stream's tracker takes).
"""

from __future__ import annotations

import dataclasses

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..data.results import FusedSequence
from ..errors import ValidationError
from .central import CentralConfig, CentralTracker, check_estimates

__all__ = ["PersonIds", "assign_person_ids", "NO_PERSON"]

#: The id of a row that no track holds (not fused successfully).
NO_PERSON = -1


class PersonIds:
    """The central tracker's person ids for fused rows (module docstring).

    config : the tracker's settings; default ``CentralConfig(frame_period_s=)``
        the fused sequence's frame period. The prior the tracker removes from
        MAP estimates is the first sequence's (``prior_mean``, ``prior_sigmas``).
    """

    def __init__(self, config: CentralConfig | None = None) -> None:
        if config is not None and not isinstance(config, CentralConfig):
            raise ValidationError(f"config must be a CentralConfig, got {type(config).__name__}")
        self.config = config
        self._tracker: CentralTracker | None = None
        self._last_frame: int | None = None

    @property
    def tracker(self) -> CentralTracker | None:
        """The tracker (None before the first frame)."""
        return self._tracker

    def start(self, *, frame_period_s: float | None, prior_mean: ArrayLike | None = None,
              prior_sigmas: ArrayLike | None = None) -> None:
        """Make the tracker (done by the first :meth:`assign`; call it before
        :meth:`frame_ids` for a stream)."""
        cfg = self.config
        if cfg is None:
            cfg = CentralConfig() if frame_period_s is None else CentralConfig(
                frame_period_s=float(frame_period_s))
        self._tracker = CentralTracker(cfg, prior_mean=prior_mean, prior_sigmas=prior_sigmas)
        self._last_frame = None

    def frame_ids(self, frame: int, states: ArrayLike, covariances: ArrayLike) -> NDArray:
        """One frame's successful estimates ``states (M, 4)``, ``covariances
        (M, 4, 4)`` -> their person ids ``(M,)`` int64, after stepping the
        frames since the last one (prediction only, while a track lives)."""
        if self._tracker is None:
            raise ValidationError("PersonIds.frame_ids before start()")
        z, r = check_estimates(states, covariances)
        return np.array(self._frame_ids(int(frame), z.tolist(), r.reshape(-1, 16).tolist()),
                        dtype=np.int64)

    def _frame_ids(self, frame: int, states: list, covariances: list) -> list[int]:
        """:meth:`frame_ids` on checked estimates in plain floats (lists)."""
        last = self._last_frame
        if last is not None and frame <= last:
            raise ValidationError(f"frame {frame} is not after the last frame tracked, {last}: "
                                  "give the rows in frame order")
        tracker = self._tracker
        if last is not None:
            for _ in range(last + 1, frame):
                if not tracker.n_tracks:
                    break  # nothing alive: the rest of the gap changes nothing
                tracker.step_ids([], [])
        ids = tracker.step_ids(states, covariances)
        self._last_frame = frame
        return ids

    def assign(self, fused: FusedSequence) -> FusedSequence:
        """``fused`` with its ``track_id`` (the rows in frame order, after
        every row given before)."""
        if not isinstance(fused, FusedSequence):
            raise ValidationError(f"fused must be a FusedSequence, got {type(fused).__name__}")
        if self._tracker is None:
            self.start(frame_period_s=fused.frame_period_s, prior_mean=fused.prior_mean,
                       prior_sigmas=fused.prior_sigmas)
        frames = np.asarray(fused.frame, dtype=np.int64)
        ids = np.full(frames.shape, NO_PERSON, dtype=np.int64)
        if frames.size:
            order = np.argsort(frames, kind="stable")
            ok = np.asarray(fused.success, dtype=bool)[order]
            good = order[ok]  # the successful rows, in frame order
            z, r = check_estimates(np.asarray(fused.state)[good],
                                   np.asarray(fused.covariance)[good])
            zl, rl = z.tolist(), r.reshape(-1, 16).tolist()
            sorted_frames = frames[order]
            # Each frame's successful rows: [lo, hi) of the successful rows.
            starts = np.flatnonzero(np.r_[True, sorted_frames[1:] != sorted_frames[:-1]])
            first_good = np.cumsum(np.r_[0, ok]).tolist()
            bounds = [first_good[i] for i in starts.tolist()] + [len(zl)]
            out = []
            for k, frame in enumerate(sorted_frames[starts].tolist()):
                lo, hi = bounds[k], bounds[k + 1]
                out += self._frame_ids(frame, zl[lo:hi], rl[lo:hi])
            ids[good] = out
        return dataclasses.replace(fused, track_id=ids)


def assign_person_ids(fused: FusedSequence, config: CentralConfig | None = None) -> FusedSequence:
    """``fused`` with the person id of every row: :class:`PersonIds` over the
    whole sequence."""
    return PersonIds(config).assign(fused)
