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
:data:`UNPLACED_LOOK_FRAMES` frames on either side. The others (an image
that walks beside the person, never with him) are flagged. A network of one
node has nothing to tie its rows to: the check leaves it alone.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["unplaced_rows", "UNPLACED_LOOK_FRAMES", "LINK_GAP_S", "MAX_WALK_MPS",
           "UNPLACED_MESSAGE"]

#: Frames on each side of a row where the chain to a row of two nodes may run
#: (5 s at 20 fps).
UNPLACED_LOOK_FRAMES = 100
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
                  decide: NDArray | None = None) -> NDArray:
    """(K,) bool: the successful one-node rows that no chain of successful
    rows ties to a row of two or more nodes (module docstring).

    frame : (K,) int, sorted; xy : (K, 2) positions; ok : (K,) the
    successful rows; kept : (K, N) the nodes each row was fused from;
    decide : the frames whose rows are judged (None: all; the others are
    context, as the stream holds them).
    """
    k, n = kept.shape
    flag = np.zeros(k, dtype=bool)
    if k == 0 or n < 2:
        return flag
    n_kept = kept.sum(axis=1)
    anchor = ok & (n_kept >= 2)
    judged = ok & (n_kept == 1)
    if decide is not None:
        judged &= np.isin(frame, np.asarray(decide))
    lone = np.flatnonzero(judged)
    w = UNPLACED_LOOK_FRAMES
    link_frames = max(1, int(round(LINK_GAP_S / frame_period_s)))
    for r in lone:
        # Each row on its own window (not the chains of others: a driver
        # that holds that window decides the row alike).
        lo, hi = np.searchsorted(frame, [frame[r] - w, frame[r] + w + 1])
        near = np.arange(lo, hi)
        near = near[ok[near]]
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
