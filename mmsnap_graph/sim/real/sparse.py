"""Sparse point clouds like those of TI's out-of-box demo.

Real demo point clouds of people walking, projected to the 2D plane, hold
only about 2-3 moving points per radar per frame, and a radar sees nothing at
all in about a quarter of its frames (in short bursts). :func:`sparse_clouds`
thins the simulator's point clouds (:func:`~mmsnap_graph.sim.simulate_recording`,
level ``"point_cloud"``: every resolvable body scatterer) to that: per node
and frame, a random 2 or 3 of the targets' points (``points_per_frame``),
none in the empty frames, which come in bursts (a two-state Markov chain
with the given ``empty_fraction`` and mean burst length), and the false
alarms kept at ``false_alarm_fraction`` of their rate. Centroids and tracks
are dropped (the chain makes them again from the thinned clouds).
"""

from __future__ import annotations

import dataclasses

import numpy as np
from numpy.typing import NDArray

from ...data.recording import Recording
from ...errors import ValidationError

__all__ = ["sparse_clouds", "empty_frame_mask"]


def empty_frame_mask(n_frames: int, empty_fraction: float, mean_burst_frames: float,
                     rng: np.random.Generator) -> NDArray:
    """(n_frames,) bool, True in empty frames: a two-state Markov chain whose
    stationary empty probability is ``empty_fraction`` and whose empty
    bursts last ``mean_burst_frames`` on average (geometric)."""
    if not 0 <= empty_fraction < 1:
        raise ValidationError(f"empty_fraction={empty_fraction!r} must be in [0, 1)")
    if not mean_burst_frames >= 1:
        raise ValidationError(f"mean_burst_frames={mean_burst_frames!r} must be >= 1")
    leave = 1.0 / float(mean_burst_frames)                       # empty -> full
    enter = leave * empty_fraction / (1.0 - empty_fraction)      # full -> empty
    if enter > 1:
        raise ValidationError("empty_fraction is too large for so short bursts")
    out = np.zeros(int(n_frames), dtype=bool)
    state = rng.random() < empty_fraction
    u = rng.random(int(n_frames))
    for k in range(int(n_frames)):
        out[k] = state
        state = (u[k] >= leave) if state else (u[k] < enter)
    return out


def _thin(det, n_frames, points_per_frame, empty, false_alarm_fraction, rng):
    """Row indices of one node's cloud to keep."""
    lo, hi = points_per_frame
    keep = []
    target = det.target_id >= 0 if det.target_id is not None else np.ones(len(det), bool)
    order = np.argsort(det.frame, kind="stable")
    bounds = np.searchsorted(det.frame[order], np.arange(n_frames + 1))
    for f in range(n_frames):
        rows = order[bounds[f]:bounds[f + 1]]
        if empty[f] or rows.size == 0:
            continue
        people = rows[target[rows]]
        k = min(int(rng.integers(lo, hi + 1)), people.size)
        keep.append(rng.choice(people, size=k, replace=False))
        alarms = rows[~target[rows]]
        keep.append(alarms[rng.random(alarms.size) < false_alarm_fraction])
    return np.sort(np.concatenate(keep)) if keep else np.zeros(0, np.int64)


def sparse_clouds(recording: Recording, *, points_per_frame: tuple[int, int] = (2, 3),
                  empty_fraction: float = 0.25, mean_burst_frames: float = 4.0,
                  false_alarm_fraction: float = 0.2, seed: int = 0) -> Recording:
    """The recording with every node's point cloud thinned (module doc).

    points_per_frame : ``(low, high)``: each non-empty frame keeps a uniform
        random number in ``low..high`` of the targets' points (all of them
        when fewer).
    empty_fraction, mean_burst_frames : :func:`empty_frame_mask`, per node.
    false_alarm_fraction : fraction of the false alarms (``target_id`` -1)
        kept in the non-empty frames.
    seed : seeds the thinning (per node).
    """
    lo, hi = (int(v) for v in points_per_frame)
    if not 1 <= lo <= hi:
        raise ValidationError(f"points_per_frame={points_per_frame!r} must be (low, high) "
                              f"with 1 <= low <= high")
    if not 0 <= false_alarm_fraction <= 1:
        raise ValidationError(f"false_alarm_fraction={false_alarm_fraction!r} must be in [0, 1]")
    out = recording
    for i, (name, node) in enumerate(recording.nodes.items()):
        if node.point_cloud is None:
            raise ValidationError(f"nodes[{name}] has no point cloud to thin")
        rng = np.random.default_rng([int(seed), i])
        det = node.point_cloud
        n_frames = int(det.frame.max()) + 1 if len(det) else 0
        empty = empty_frame_mask(n_frames, empty_fraction, mean_burst_frames, rng)
        rows = _thin(det, n_frames, (lo, hi), empty, false_alarm_fraction, rng)
        out = out.with_node(dataclasses.replace(node, point_cloud=det.select(rows),
                                                centroids=None, tracks=None))
    return out
