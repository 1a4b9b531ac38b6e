"""Fused rows whose covariance cannot be trusted because the association
split one frame's detections (docs/CONVENTIONS.md).

In a frame where every node that sees something has exactly one detection,
the association (:mod:`mmsnap_graph.fusion.association`) may still leave a
node's detection in a group of its own: the detections fail its chi-square
gate as one target. Either that node's detection is an outlier (a ghost, or
the tail of a heavy-tailed centroid) or it sees a target no other node sees;
the data cannot tell which. The row fused from it alone is, in the first
case, conditioned on an error large enough to fail the gate, and its
covariance (that of one clean detection) is too small: on the README's tour
(network C, point-cloud centroids, 600 frames, seeds 1-3) 40-64 such rows
had a mean NEES of 19-30 and pulled the fused mean NEES from 4.3-6.9 to
5.6-9.2. :func:`split_singles` finds these rows; :func:`split_rows` picks
those to mark ``success=False`` (:attr:`Status.RESIDUAL_TEST_FAILED`) with
:data:`SPLIT_MESSAGE`, as the robust gate marks a frame it cannot repair
(``fuse_recording`` marks them through
:meth:`~mmsnap_graph.fusion.recording.rows.FusedRows.flag`). The estimate
stays in ``/fused`` for whoever wants it.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ...data.results import Status

__all__ = ["split_singles", "split_rows", "SPLIT_MESSAGE"]

#: The message of a row :func:`split_rows` picks.
SPLIT_MESSAGE = ("one node's only detection of the frame fails the association gate with the "
                 "other nodes' (an outlier, or a target only it sees): covariance not trusted")


def split_singles(frame: ArrayLike, detection_index: ArrayLike) -> NDArray:
    """(K,) bool: the one-node groups of frames in which every node with a
    detection has exactly one and the frame holds other groups.

    frame : (K,) int, each group's frame; detection_index : (K, N) int, the
    member detection of each node (-1 = none), as
    :class:`~mmsnap_graph.fusion.recording.sequence.DetectionGroups`.
    """
    fr = np.asarray(frame, dtype=np.int64)
    obs = np.asarray(detection_index) >= 0
    out = np.zeros(fr.size, bool)
    if fr.size == 0:
        return out
    frames, inverse, groups = np.unique(fr, return_inverse=True, return_counts=True)
    per_node = np.zeros((frames.size, obs.shape[1]), np.int64)
    np.add.at(per_node, inverse, obs.astype(np.int64))
    one_each = np.all(per_node <= 1, axis=1)
    single = obs.sum(axis=1) == 1
    return single & one_each[inverse] & (groups[inverse] > 1)


def split_rows(frame: ArrayLike, detection_index: ArrayLike, status: ArrayLike, *,
               keep_sole: bool = False) -> NDArray:
    """(K,) bool: the successful rows (``status`` OK) of :func:`split_singles`,
    which the caller marks :attr:`Status.RESIDUAL_TEST_FAILED` with
    :data:`SPLIT_MESSAGE`.

    keep_sole : leave a row that is the only successful row of its frame (after
    the motion check, which has flagged the frame's other rows and kept this
    one because the neighbouring frames confirm it)."""
    ok = np.asarray(status) == Status.OK
    rows = split_singles(frame, detection_index) & ok
    if keep_sole and rows.any():
        fr = np.asarray(frame, dtype=np.int64)
        _, inverse, counts = np.unique(fr[ok], return_inverse=True, return_counts=True)
        n_ok = np.zeros(fr.size, np.int64)
        n_ok[ok] = counts[inverse]
        rows &= n_ok > 1
    return rows
