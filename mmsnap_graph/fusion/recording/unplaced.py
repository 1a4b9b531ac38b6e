"""The placement check (:class:`~mmsnap_graph.fusion.config.UnplacedCheck`):
a row seen by one radar alone that nothing ties to a person seen by two.

One radar's range and angle place a detection; they cannot tell a person
from a one-bounce multipath image (radar -> person -> wall -> radar, seen at
the wall along the mirror image's bearing) or a static reflector that
flickers. Where another radar covers that place the coverage check
(:mod:`.coverage`) judges; where none does (behind another radar, beyond the
common area, or in a network of two) nothing can, and the row went out with
the small covariance of a good one-radar fix: a random layout of three
radars at 20 fps with two walkers kept 24 such rows 6-7 m off (beyond the
wall behind a radar, NEES over 500; ``tools/random_layouts.py``).

A person seen by one radar alone got there by walking: :func:`unplaced_rows`
keeps a one-node row when a chain of successful rows, each within
``body_m + MAX_WALK_MPS * dt`` of the next and at most :data:`LINK_GAP_S`
apart, leads from it to a row seen by two or more nodes within
:data:`UNPLACED_LOOK_BACK_FRAMES` frames before it or
:data:`UNPLACED_LOOK_AHEAD_FRAMES` after it. The chain runs over the rows as
solved (before the other checks: a stream holds its past frames so), the row
judged is one the other checks kept. The others (an image
that walks beside the person, never with him) are flagged. A network of one
node has nothing to tie its rows to: the check leaves it alone.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from .motion_check import MOTION_CONTEXT_FRAMES

__all__ = ["unplaced_rows", "UNPLACED_LOOK_BACK_FRAMES", "UNPLACED_LOOK_AHEAD_FRAMES",
           "LINK_GAP_S", "MAX_WALK_MPS", "UNPLACED_MESSAGE"]

#: Frames before a row where the chain to a row of two nodes may run (5 s at
#: 20 fps) ...
UNPLACED_LOOK_BACK_FRAMES = 100
#: ... and after it: the motion check's look-around, so that a stream that
#: waits that long for the other checks decides this one as ``mmsnap fuse``.
UNPLACED_LOOK_AHEAD_FRAMES = MOTION_CONTEXT_FRAMES
#: Largest gap (s) between two linked rows: a sparse cloud misses a walker
#: for a few frames now and then.
LINK_GAP_S = 0.5
#: Fastest walk (m/s) between two linked rows.
MAX_WALK_MPS = 2.5
UNPLACED_MESSAGE = ("placement check: seen by node {node} alone and tied by no walk to a "
                    "target seen by two nodes (a multipath image or clutter one radar cannot "
                    "tell from a person)")


def unplaced_rows(frame: NDArray, xy: NDArray, ok: NDArray, kept: NDArray, *,
                  frame_period_s: float, body_m: float,
                  decide: NDArray | None = None, solved: NDArray | None = None,
                  seen: NDArray | None = None) -> NDArray:
    """(K,) bool: the successful one-node rows that no chain of successful
    rows ties to a row of two or more nodes (module docstring).

    frame : (K,) int, sorted; xy : (K, 2) positions; ok : (K,) the
    successful rows; kept : (K, N) the nodes each row was fused from;
    decide : the frames whose rows are judged (None: all; the others are
    context, as the stream holds them); solved, seen : (K,) and (K, N) the
    rows that the solve fused and the nodes they were grouped with, before
    the other checks: the chain's links and anchors (default ``ok``, ``kept``).
    """
    k, n = kept.shape
    flag = np.zeros(k, dtype=bool)
    if k == 0 or n < 2:
        return flag
    solved = ok if solved is None else np.asarray(solved, dtype=bool)
    seen = kept if seen is None else np.asarray(seen, dtype=bool)
    anchor = solved & (seen.sum(axis=1) >= 2)
    judged = ok & (kept.sum(axis=1) == 1)
    if decide is not None:
        judged &= np.isin(frame, np.asarray(decide))
    lone = np.flatnonzero(judged)
    link_frames = max(1, int(round(LINK_GAP_S / frame_period_s)))
    for r in lone:
        # Each row on its own window (not the chains of others: a driver
        # that holds that window decides the row alike).
        lo, hi = np.searchsorted(frame, [frame[r] - UNPLACED_LOOK_BACK_FRAMES,
                                         frame[r] + UNPLACED_LOOK_AHEAD_FRAMES + 1])
        near = np.arange(lo, hi)
        near = near[solved[near] | (near == r)]
        f, p = frame[near], xy[near]
        reached = near == r
        frontier = reached.copy()
        while frontier.any():
            src = np.flatnonzero(frontier)
            gap = np.abs(f[None, :] - f[src, None])
            dist = np.linalg.norm(p[None, :, :] - p[src, None, :], axis=-1)
            link = (gap <= link_frames) & (dist <= body_m + MAX_WALK_MPS * gap * frame_period_s)
            new = link.any(axis=0) & ~reached
            reached |= new
            frontier = new
            if np.any(anchor[near[new]]):
                break
        flag[r] = not np.any(anchor[near[reached]])
    return flag
