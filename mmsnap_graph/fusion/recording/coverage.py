"""The coverage check of :func:`~mmsnap_graph.fusion.recording.sequence.fuse_recording`
(docs/ROBUST.md, "The coverage check"): a target is seen by every node that
looks at it.

A multipath image (a person's mirror image through a wall) moves like a
walker, so the residual gate and the motion check keep it; but a node sees
it only in the frames where its signal happens to reflect off that wall.
Another node whose field of view covers the image's place looks there and
sees nothing, frame after frame; a real target is seen by such a node in
nearly every frame.

:func:`uncovered_rows` finds the successful rows with a node that covers
their position (within :data:`COVERAGE_FOV_RAD` of its boresight, between
:data:`COVERAGE_MIN_RANGE_M` and its farthest detection of the recording),
detects something in the frames around and takes part in fewer than
:data:`COVERAGE_MIN_FRAMES` of the rows of those frames that follow the
row's motion (the row itself and the rows of the
:data:`~.motion_check.MOTION_WINDOW_FRAMES` frames on each side within
``body_m`` of its position carried by its velocity). It cannot judge a
place that only the nodes that see the image cover (behind another radar,
say): the room's bounds can.

A node's reach is how far it looks, not how far the walkers went: the
farthest of its detections at every level the recording holds (its point
cloud, static scene and false alarms included, and its centroids). In a
small room a walker stays within a few metres of every radar while his
multipath images lie beyond him (a one-bounce image at or beyond the wall);
a reach taken from the node's own centroids, which the signal chain's scene
filters leave at the walkers, left the images' places uncovered
(tests/fusion/recording/test_coverage.py::test_a_node_covers_places_beyond_where_the_walkers_went).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from ...data.recording import NodeData
from .motion_check import MOTION_WINDOW_FRAMES

__all__ = ["uncovered_rows", "detection_reach_m", "coverage_reach_m", "declared_reach_m",
           "REACH_METADATA_KEY", "COVERAGE_FOV_RAD", "COVERAGE_MIN_RANGE_M",
           "COVERAGE_MIN_FRAMES", "COVERAGE_MIN_NODES"]

#: A node covers a place within this angle of its boresight (TI's antennas
#: see +-60 degrees; 5 degrees of margin for the edge, where the detection
#: probability falls).
COVERAGE_FOV_RAD = np.deg2rad(55.0)
#: ... and at least this far from it (m), and no farther than its farthest
#: detection of the recording.
COVERAGE_MIN_RANGE_M = 0.5
#: A covering node must see the target in at least this many of the frames
#: around (``2 MOTION_WINDOW_FRAMES + 1``): a multipath image via one wall
#: is seen now and then by each node that sees that wall; a person in
#: nearly every frame.
COVERAGE_MIN_FRAMES = 2
#: Nodes a network needs for the check. With two, the other node is the only
#: witness: on a sparse cloud it misses a walker for a few frames now and
#: then (docs/ROBUST.md gives the figure), so a two-node network relies on
#: the room's bounds (``--bounds``, ``--in-front``) for mirror images instead.
COVERAGE_MIN_NODES = 3


def detection_reach_m(node: NodeData) -> float:
    """How far ``node`` looks (m): the farthest range of its detections at
    every level it holds (point cloud and centroids); 0 without any."""
    ranges = [d.range_m for d in (node.point_cloud, node.centroids) if d is not None and len(d)]
    return float(max((r.max() for r in ranges), default=0.0))


#: A recording's metadata key ``{node}_coverage_reach_m``: the reach its
#: maker declared for the node (``mmsnap live --record``: the board's
#: ``.cfg`` maximum range, what live's coverage check took).
REACH_METADATA_KEY = "{node}_coverage_reach_m"


def declared_reach_m(metadata, node_names) -> dict:
    """The reaches a recording's ``metadata`` declares (:data:`REACH_METADATA_KEY`),
    node -> m, for the nodes that have one."""
    out = {}
    for name in node_names:
        declared = metadata.get(REACH_METADATA_KEY.format(node=name))
        if declared is not None:
            out[name] = float(declared)
    return out


def coverage_reach_m(recording) -> dict:
    """Each node's reach for the coverage check of ``recording``: the one its
    metadata declares (:func:`declared_reach_m`), else
    :func:`detection_reach_m` of its detections."""
    declared = declared_reach_m(recording.metadata, recording.node_names)
    return {name: declared[name] if name in declared
            else detection_reach_m(recording.nodes[name]) for name in recording.node_names}


def _covering(xy: NDArray, poses: NDArray, reach: NDArray) -> NDArray:
    """(K, N) True where node n covers position ``xy[k]``."""
    d = xy[:, None, :] - poses[None, :, :2]
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    across = c * d[..., 0] + s * d[..., 1]
    ahead = -s * d[..., 0] + c * d[..., 1]
    r = np.hypot(across, ahead)
    return (ahead > 0) & (np.abs(np.arctan2(across, ahead)) <= COVERAGE_FOV_RAD) \
        & (r >= COVERAGE_MIN_RANGE_M) & (r <= reach)


def uncovered_rows(frame: NDArray, state: NDArray, ok: NDArray, observed: NDArray,
                   ranges: NDArray, poses: NDArray, *,
                   frame_period_s: float, body_m: float,
                   reach_m: NDArray | None = None,
                   decide: NDArray | None = None) -> tuple[NDArray, NDArray]:
    """``(flag (K,), node (K,))``: the successful rows (``ok``) a covering
    node never sees (module doc), and the first such node (-1: none).

    frame : (K,) int, sorted; state : (K, 4); observed : (K, N) bool, the
    nodes whose detections a row was grouped with (kept or left out by the
    gate: either way the node saw something there); ranges : (K, N) the
    rows' measured ranges (any value where not observed); poses : (N, 3);
    reach_m : (N,) each node's reach (:func:`detection_reach_m`); None: the
    farthest of its ``ranges`` (a reach of where the targets went);
    decide : the frames whose rows are judged (None: all; the others are
    context, never flagged: a stream deciding one frame, each row's verdict
    being of the rows around it alone).
    """
    k, n = observed.shape
    flag = np.zeros(k, dtype=bool)
    first = np.full(k, -1, dtype=np.int64)
    if k == 0 or n < COVERAGE_MIN_NODES or not ok.any():
        return flag, first
    reach = np.array([ranges[observed[:, i], i].max() if observed[:, i].any() else 0.0
                      for i in range(n)]) if reach_m is None else np.asarray(reach_m, dtype=float)
    cover = _covering(state[:, :2], poses, reach)
    judged = ok if decide is None else ok & np.isin(frame, decide)
    cand = np.flatnonzero(judged & np.any(cover & ~observed, axis=1))
    w = MOTION_WINDOW_FRAMES
    for r in cand:
        lo, hi = np.searchsorted(frame, [frame[r] - w, frame[r] + w + 1])
        near = np.arange(lo, hi)
        active = observed[near].any(axis=0)       # nodes that detect something then
        dt = (frame[near] - frame[r]) * frame_period_s
        carried = state[r, :2] + dt[:, None] * state[r, 2:]
        same = ok[near] & (np.hypot(*(state[near, :2] - carried).T) < body_m)
        same[near == r] = True
        rows = near[same]
        # A node's detection grouped with the target (kept or left out by the
        # gate) is a sighting: it looked and saw something there.
        seen = np.array([np.unique(frame[rows[observed[rows, i]]]).size for i in range(n)])
        missing = cover[r] & active & (seen < COVERAGE_MIN_FRAMES)
        if missing.any():
            flag[r] = True
            first[r] = int(np.argmax(missing))
    return flag, first
