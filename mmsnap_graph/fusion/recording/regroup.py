"""One cluster per body before a recording's association (docs/ROBUST.md,
"One centroid per body"): :func:`merge_body_detections`.

A radar often sees one person as two or more clusters (torso and arm, the
two sides of the body). A node's centroids of one frame closer than a
merge radius (in the node's own Cartesian frame) are one body: they are
replaced by their mean position and mean Doppler before the association, so
that no half of a body enters a fused row on its own and biases it. Two
people closer than that to each other become one detection of that node.
"""

from __future__ import annotations

from itertools import combinations

import numpy as np
from numpy.typing import NDArray

from ...data.body import CENTROID_MERGE_RADIUS_M


__all__ = ["merge_body_detections", "DEFAULT_MERGE_BODY_M"]

#: The merge radius (m): a node's centroids of one frame closer than this are
#: one body (:data:`~mmsnap_graph.data.body.CENTROID_MERGE_RADIUS_M` says why).
DEFAULT_MERGE_BODY_M = CENTROID_MERGE_RADIUS_M


def _local_xy(z: NDArray) -> NDArray:
    s = np.clip(z[:, 1] / np.pi, -1.0, 1.0)
    return np.stack([z[:, 0] * s, z[:, 0] * np.sqrt(1.0 - s * s)], axis=1)


def merge_body_detections(frame: NDArray, meas: NDArray, body_m: float
                          ) -> tuple[NDArray, NDArray]:
    """One node's detections with each frame's clusters of one body merged.

    frame : (K,) int; meas : (K, 3) ``(range_m, omega_rad, doppler_mps)``.
    Detections of one frame closer than ``body_m`` (single linkage, in the
    node's Cartesian frame) are one body: the first of them takes their mean
    position and Doppler. Returns ``(keep (K,) bool, meas (K, 3))``: the
    detections that stay (the first of each body) and the measurements,
    merged where they were.
    """
    frame = np.asarray(frame)
    meas = np.array(meas, dtype=float, copy=True)
    keep = np.ones(frame.size, dtype=bool)
    if frame.size < 2:
        return keep, meas
    order = np.argsort(frame, kind="stable")
    starts = np.concatenate([[0], np.flatnonzero(np.diff(frame[order])) + 1])
    sizes = np.diff(np.concatenate([starts, [frame.size]]))
    xy = _local_xy(meas)
    for s, n in zip(starts[sizes > 1], sizes[sizes > 1]):
        rows = order[s:s + n]
        near = np.hypot(*(xy[rows][:, None, :] - xy[rows][None, :, :]).transpose(2, 0, 1)) < body_m
        label = np.arange(n)
        for _ in range(n):  # single linkage: the smallest label spreads
            new = np.min(np.where(near, label[None, :], n), axis=1)
            if np.array_equal(new, label):
                break
            label = new
        for lab in np.unique(label):
            members = rows[label == lab]
            if members.size > 1:
                p = xy[members].mean(axis=0)
                r = float(np.hypot(*p))
                meas[members[0]] = (r, np.pi * p[0] / max(r, 1e-12), meas[members, 2].mean())
                keep[members[1:]] = False
    return keep, meas
