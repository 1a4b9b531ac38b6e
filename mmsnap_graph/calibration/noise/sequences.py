"""Each node's single-target sequences of centroids and the ghosts in them
(the noise estimators' screens; docs/CALIBRATION.md, "Noise from the data")."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from ...data.recording import Detections

__all__ = ["GHOST_K", "GHOST_REACH", "ghost_rows", "single_target_sequences"]

#: Threshold (robust sigmas) and reach (frames on either side) of :func:`ghost_rows`.
GHOST_K = 5.0
GHOST_REACH = 3


def single_target_sequences(det: Detections) -> list[NDArray]:
    """Row indices of each single-target sequence of ``det``, by frame: per
    ``target_id`` when the rows are labelled, else the frames with exactly
    one centroid."""
    order = np.argsort(det.frame, kind="stable")
    labels = det.target_id
    if labels is not None and np.any(labels >= 0):
        groups = [order[labels[order] == t] for t in np.unique(labels[labels >= 0])]
    else:
        groups = [order]
    out = []
    for rows in groups:
        frames, counts = np.unique(det.frame[rows], return_counts=True)
        single = np.isin(det.frame[rows], frames[counts == 1])
        out.append(rows[single])
    return out


def ghost_rows(detections: Detections, *, k: float = GHOST_K) -> NDArray:
    """(K,) bool: centroids of ``detections`` that are ghosts in their own
    single-target sequence: some component further than ``k`` robust sigmas
    from the median of five predictions from its neighbours (the means of the
    1st, 2nd and 3rd neighbours on either side, and the two one-sided linear
    extrapolations), which a ghost among the neighbours cannot move much.
    The first and last three rows of a sequence, and rows outside a
    single-target sequence, are not flagged (the trimmed scale of
    :func:`temporal_noise` takes care of what slips through)."""
    flag = np.zeros(len(detections), bool)
    for rows in single_target_sequences(detections):
        if rows.size < 2 * GHOST_REACH + 1:
            continue
        z = detections.measurements[rows]
        z[:, 1] = np.unwrap(z[:, 1])
        c = slice(GHOST_REACH, z.shape[0] - GHOST_REACH)

        def at(offset):
            return z[GHOST_REACH + offset: z.shape[0] - GHOST_REACH + offset]

        pred = np.stack([(at(-1) + at(1)) / 2, (at(-2) + at(2)) / 2, (at(-3) + at(3)) / 2,
                         2 * at(-1) - at(-2), 2 * at(1) - at(2)])
        dev = z[c] - np.median(pred, axis=0)
        scale = 1.4826 * np.median(np.abs(dev), axis=0)
        flag[rows[c]] = np.any(np.abs(dev) > k * np.maximum(scale, 1e-12), axis=1)
    return flag
