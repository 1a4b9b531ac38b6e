"""Two corrections of a recording's grouping of centroids into targets
(docs/ROBUST.md, "One cluster per body and the best consistent subset"):

- :func:`merge_body_detections`: one body is one detection. A node's
  centroids of one frame closer than a body's width (``body_m``, in the
  node's own Cartesian frame) are one body split into clusters (each radar
  sees parts of a person as separate clusters; the rule of the room's body
  check, with the detections' covariances); they are replaced by their
  mean position and mean Doppler before the association, so that no half of
  a body enters a fused row on its own and biases it.
- :func:`best_subset_groups`: in a frame where every node has one detection
  and they do not all fall in one gate, the association (nodes taken in
  order) may join a ghost of the first node with the second node's detection
  and leave the third node's, which agrees with the second, on its own. The
  frame is regrouped order-independently instead: the largest subset whose
  every member passes the gate against the others' fused position, of least
  scatter among those of its size, is one target; the rest are grouped the
  same way.
"""

from __future__ import annotations

from itertools import combinations

import numpy as np
from numpy.typing import NDArray

from factors.models import detection_to_global

from ..association import detection_information, detection_position_covariance
from .room import BODY_CHI2

__all__ = ["merge_body_detections", "best_subset_groups", "MAX_SUBSET_NODES"]

#: Frames with more observing nodes keep the association's grouping (the
#: subsets grow as 2^N).
MAX_SUBSET_NODES = 10
_ORIGIN = np.zeros(3)


def _local_xy(z: NDArray) -> NDArray:
    s = np.clip(z[:, 1] / np.pi, -1.0, 1.0)
    return np.stack([z[:, 0] * s, z[:, 0] * np.sqrt(1.0 - s * s)], axis=1)


def merge_body_detections(frame: NDArray, meas: NDArray, noise, body_m: float
                          ) -> tuple[NDArray, NDArray]:
    """One node's detections with each frame's clusters of one body merged.

    frame : (K,) int; meas : (K, 3) ``(range_m, omega_rad, doppler_mps)``;
    noise : the node's :class:`MeasurementNoise`. Two detections of one frame
    are one body by the rule of the room's body check
    (:mod:`~mmsnap_graph.fusion.recording.room`), in the node's Cartesian
    frame: their distance ``d`` below ``body_m``, or
    ``d' (C_a + C_b + (body_m / 2)^2 I)^-1 d`` within the 99% chi-square(2)
    quantile (``C`` their position covariances). A body (single linkage) is
    replaced by its first detection with the mean position and Doppler.
    Returns ``(keep (K,) bool, meas (K, 3))``: the detections that stay (the
    first of each body) and the measurements, merged where they were.
    """
    frame = np.asarray(frame)
    meas = np.array(meas, dtype=float, copy=True)
    keep = np.ones(frame.size, dtype=bool)
    if frame.size < 2:
        return keep, meas
    order = np.argsort(frame, kind="stable")
    cuts = np.flatnonzero(np.diff(frame[order])) + 1
    starts = np.concatenate([[0], cuts])
    sizes = np.diff(np.concatenate([starts, [frame.size]]))
    xy = _local_xy(meas)
    extent = (body_m / 2.0) ** 2 * np.eye(2)
    for s, n in zip(starts[sizes > 1], sizes[sizes > 1]):
        rows = order[s:s + n]
        label = np.arange(n)
        with np.errstate(all="ignore"):
            cov = detection_position_covariance(meas[rows, 0], meas[rows, 1], _ORIGIN, noise)
        d = xy[rows][:, None, :] - xy[rows][None, :, :]
        m2 = np.nan_to_num(np.einsum("abi,abi->ab", d, np.linalg.solve(
            cov[:, None] + cov[None, :] + extent, d[..., None])[..., 0]), nan=np.inf)
        near = (np.hypot(d[..., 0], d[..., 1]) < body_m) | (m2 <= BODY_CHI2)
        for _ in range(n):  # single linkage: spread the smallest label
            new = np.min(np.where(near, label[None, :], n), axis=1)
            if np.array_equal(new, label):
                break
            label = new
        for lab in np.unique(label):
            members = rows[label == lab]
            if members.size < 2:
                continue
            p = xy[members].mean(axis=0)
            r = float(np.hypot(*p))
            meas[members[0]] = (r, np.pi * p[0] / max(r, 1e-12), meas[members, 2].mean())
            keep[members[1:]] = False
    return keep, meas


def _scatter(pos: NDArray, info: NDArray) -> tuple[NDArray, float]:
    """``(leave-one-out squared distances (k,), total scatter)`` of a subset."""
    total = info.sum(axis=0)
    eta = np.einsum("kij,kj->ki", info, pos)
    mean = np.linalg.solve(total, eta.sum(axis=0))
    d = pos - mean
    chi2 = float(np.einsum("ki,kij,kj->", d, info, d))
    loo = np.empty(pos.shape[0])
    for i in range(pos.shape[0]):
        rest = total - info[i]
        m = np.linalg.solve(rest, eta.sum(axis=0) - eta[i])
        s = np.linalg.inv(rest) + np.linalg.inv(info[i])
        e = pos[i] - m
        loo[i] = float(e @ np.linalg.solve(s, e))
    return loo, chi2


def best_subset_groups(z: NDArray, poses: NDArray, noise, gate: float) -> list[list[int]] | None:
    """The groups (lists of node indices) of one frame in which every node
    has at most one detection: ``z (N, 3)`` the detections (NaN rows: none),
    ``poses (N, 3)``, ``noise`` one :class:`MeasurementNoise` per node,
    ``gate`` the association's chi-square (2 dof) gate. The largest subset
    whose every member is within the gate of the others' fused position, of
    least scatter among those of its size, is a group; the rest are grouped
    alike. None when a covariance is degenerate or more than
    :data:`MAX_SUBSET_NODES` nodes observe (the caller keeps its grouping)."""
    nodes = [n for n in range(z.shape[0]) if np.isfinite(z[n, 0])]
    if len(nodes) > MAX_SUBSET_NODES:
        return None
    with np.errstate(all="ignore"):
        pos = np.stack([detection_to_global(z[n, 0], z[n, 1], poses[n]) for n in nodes])
        cov = np.stack([detection_position_covariance(z[n, 0], z[n, 1], poses[n], noise[n])
                        for n in nodes])
    info, ok = detection_information(cov)
    if not np.all(ok):
        return None
    left = list(range(len(nodes)))
    groups: list[list[int]] = []
    while left:
        best = None
        for size in range(len(left), 1, -1):
            for sub in combinations(left, size):
                idx = list(sub)
                loo, chi2 = _scatter(pos[idx], info[idx])
                if np.all(loo <= gate) and (best is None or chi2 < best[1]):
                    best = (idx, chi2)
            if best is not None:
                break
        chosen = best[0] if best is not None else [left[0]]
        groups.append([nodes[i] for i in chosen])
        left = [i for i in left if i not in chosen]
    return groups
