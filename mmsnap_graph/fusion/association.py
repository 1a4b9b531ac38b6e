"""Which centroids of different nodes are the same target, frame by frame.

With several targets in view each node reports several centroids per frame.
Before one-shot fusion the centroids are grouped across nodes: every
detection is mapped to the global frame with the calibrated node pose
(:func:`factors.models.detection_to_global`, docs/CONVENTIONS.md, the corrected eq. 19), its
2x2 position covariance is propagated from the measurement noise (range and
spatial frequency), and the nodes are taken in order: the first node's
detections seed the groups, each further node's detections are assigned to
the existing groups by a gated minimum-cost assignment
(:func:`scipy.optimize.linear_sum_assignment` on the squared Mahalanobis
distance, pairs beyond the chi-square gate forbidden); a detection left
unassigned starts a group of its own (a target only that node sees, or a false
alarm). A group's position is the information-weighted mean of its members.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from itertools import combinations
from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import linear_sum_assignment

from factors.models import detection_covariance_global, detection_to_global

from ..errors import ValidationError
from .._validation import as_float_array, check_finite, chi2_gate
from ..data.noise import MeasurementNoise
from .problem import check_node_noise

__all__ = [
    "FrameAssociation",
    "group_distance2",
    "detection_position_covariance",
    "associate_frame",
    "gate_threshold",
    "detection_information",
    "MIN_VARIANCE_M2",
    "MAX_CONDITION",
    "MAX_SUBSET_NODES",
]

# Cost of a forbidden pair in the assignment (beyond any gated cost).
_FORBIDDEN = 1e12


def gate_threshold(gate_probability: float) -> float:
    """Squared-Mahalanobis gate of a 2D position: ``chi2.ppf(p, 2)``, in
    closed form (2 degrees of freedom: ``-2 log(1 - p)``)."""
    return chi2_gate(gate_probability, 2)


def _scaled_2x2(a: NDArray) -> tuple[NDArray, NDArray, NDArray]:
    """``(scale (...,), a / scale, det(a / scale))`` of 2x2 matrices: the
    closed forms below work on the scaled matrix (no overflow or underflow
    of the determinant)."""
    scale = np.max(np.abs(a), axis=(-1, -2))
    scale = np.where((scale > 0) & np.isfinite(scale), scale, 1.0)
    b = a / scale[..., None, None]
    det = b[..., 0, 0] * b[..., 1, 1] - b[..., 0, 1] * b[..., 1, 0]
    return scale, b, det


def _inv_2x2(a: NDArray) -> NDArray:
    """Inverse of (..., 2, 2) matrices in closed form (no LAPACK call: small
    matrices, many calls)."""
    scale, b, det = _scaled_2x2(a)
    out = np.empty_like(b)
    out[..., 0, 0], out[..., 1, 1] = b[..., 1, 1], b[..., 0, 0]
    out[..., 0, 1], out[..., 1, 0] = -b[..., 0, 1], -b[..., 1, 0]
    return out / (det * scale)[..., None, None]


def _mahalanobis2_2x2(d: NDArray, s: NDArray) -> NDArray:
    """``d^T s^-1 d`` of (..., 2) vectors and (..., 2, 2) matrices (inf or
    NaN where ``s`` is singular)."""
    with np.errstate(all="ignore"):
        scale, b, det = _scaled_2x2(s)
        q = (b[..., 1, 1] * d[..., 0] ** 2 - (b[..., 0, 1] + b[..., 1, 0]) * d[..., 0] * d[..., 1]
             + b[..., 0, 0] * d[..., 1] ** 2)
        return q / (det * scale)


def detection_position_covariance(
    range_m: ArrayLike, omega_rad: ArrayLike, node_pose: ArrayLike,
    noise: MeasurementNoise = MeasurementNoise(),
) -> NDArray:
    """Covariance of detections mapped to the global frame, (..., 2, 2) m^2.

    First-order propagation of the range and spatial-frequency noise through
    ``p = p_i + R(phi_i) (R s, R sqrt(1 - s^2))``, ``s = Omega / pi``:
    ``d p_local / d R = (s, c)``, ``d p_local / d Omega = (R / pi) (1, -s / c)``
    with ``c = sqrt(1 - s^2)`` floored at ``factors.models.DETECTION_MIN_COS``
    near end-fire (:func:`factors.models.detection_covariance_global`, with the
    sigmas of ``noise``).

    range_m, omega_rad : (...,); node_pose : (..., 3) or (3,);
    noise : the measurement sigmas (range and spatial frequency are used). No validation.
    """
    return detection_covariance_global(range_m, omega_rad, node_pose, noise.range_m, noise.omega_rad)


@dataclass(frozen=True, kw_only=True, slots=True)
class FrameAssociation:
    """Groups of one frame's detections, one group per (putative) target.

    members : (G, N) int, row index of each node's detection in the group
        (into that node's per-frame detections), -1 where the node has none.
    position_m : (G, 2) information-weighted mean of the members' global positions.
    covariance_m2 : (G, 2, 2) its covariance.
    """

    members: NDArray
    position_m: NDArray
    covariance_m2: NDArray

    def __len__(self) -> int:
        return int(self.members.shape[0])


#: A detection's 2x2 position covariance is usable for gating and weighting
#: when its smallest eigenvalue is above this (m^2) and above
#: ``MAX_CONDITION``-th of its largest. Range 0 (at any angle), a range of
#: 1e-300 m or sigmas of 1e-300 give a singular one (numpy would raise LinAlgError).
MIN_VARIANCE_M2 = 1e-100
MAX_CONDITION = 1e12
#: A frame of one detection per node that the nodes taken in order split is
#: regrouped order-independently (:func:`_best_subsets`): every subset is
#: tried up to this many detections (the subsets grow as 2^N); with more,
#: the detection farthest from the others' is dropped until the rest agree.
MAX_SUBSET_NODES = 5


def detection_information(covariance_m2: NDArray) -> tuple[NDArray, NDArray]:
    """``(information (..., 2, 2), ok (...,))`` of detection covariances:
    ``ok`` where the covariance is finite and regular (:data:`MIN_VARIANCE_M2`,
    :data:`MAX_CONDITION`); the information is its inverse there and zero
    elsewhere (a degenerate detection carries no usable position weight)."""
    cov = np.asarray(covariance_m2, dtype=float)
    finite = np.all(np.isfinite(cov), axis=(-1, -2))
    safe = np.where(finite[..., None, None], cov, np.eye(2))
    safe = 0.5 * (safe + np.swapaxes(safe, -1, -2))
    with np.errstate(all="ignore"):
        # Eigenvalues of the symmetric 2x2 in closed form, on the scaled
        # matrix: the larger from the trace, the smaller as det / larger.
        scale, b, det = _scaled_2x2(safe)
        big = 0.5 * (b[..., 0, 0] + b[..., 1, 1]) + np.hypot(0.5 * (b[..., 0, 0] - b[..., 1, 1]),
                                                             b[..., 0, 1])
        small = np.where(big > 0, det / np.where(big > 0, big, 1.0), -np.inf)
    ok = finite & (small * scale > MIN_VARIANCE_M2) & (small * MAX_CONDITION > big)
    info = _inv_2x2(np.where(ok[..., None, None], safe, np.eye(2)))
    return np.where(ok[..., None, None], info, 0.0), ok


class _Groups:
    """The groups of :func:`associate_frame` as they grow: members, summed
    information and information vector; a degenerate detection's group keeps
    its position and covariance as they are and takes no other member."""

    def __init__(self, n_nodes: int) -> None:
        self.n_nodes = n_nodes
        self.members: list[list[int]] = []
        self.info: list[NDArray] = []
        self.eta: list[NDArray] = []
        self.fixed: list[tuple[NDArray, NDArray] | None] = []

    def gated(self) -> NDArray:
        """Indices of the groups other detections may join."""
        return np.array([g for g, f in enumerate(self.fixed) if f is None], dtype=np.int64)

    def add(self, g: int, n: int, k: int, pos: NDArray, cov: NDArray, info: NDArray,
            ok: bool) -> None:
        if g < 0:
            self.members.append([-1] * self.n_nodes)
            self.info.append(np.zeros((2, 2)))
            self.eta.append(np.zeros(2))
            self.fixed.append(None if ok else (pos, cov))
            g = len(self.members) - 1
        self.members[g][n] = k
        self.info[g] = self.info[g] + info
        self.eta[g] = self.eta[g] + info @ pos

    def result(self) -> FrameAssociation:
        if not self.members:
            return FrameAssociation(members=np.zeros((0, self.n_nodes), dtype=np.int64),
                                    position_m=np.zeros((0, 2)),
                                    covariance_m2=np.zeros((0, 2, 2)))
        info = np.stack(self.info)
        regular = np.array([f is None for f in self.fixed])
        cov_g = np.zeros_like(info)
        cov_g[regular] = _inv_2x2(info[regular])
        cov_g = 0.5 * (cov_g + np.swapaxes(cov_g, -1, -2))
        pos = np.einsum("gij,gj->gi", cov_g, np.stack(self.eta))
        for g in np.flatnonzero(~regular):
            pos[g], cov_g[g] = self.fixed[g]
        return FrameAssociation(members=np.asarray(self.members, dtype=np.int64),
                                position_m=pos, covariance_m2=cov_g)


def _assign(groups: _Groups, pos: NDArray, cov: NDArray, ok: NDArray, gate: float) -> NDArray:
    """Group of each detection (-1: none) by gated minimum-cost assignment
    against the groups that take members; degenerate detections take none."""
    assigned = np.full(pos.shape[0], -1)
    cand = groups.gated()
    usable = np.flatnonzero(ok)
    if cand.size == 0 or usable.size == 0:
        return assigned
    cov_g = _inv_2x2(np.stack([groups.info[g] for g in cand]))
    mean_g = np.einsum("gij,gj->gi", cov_g, np.stack([groups.eta[g] for g in cand]))
    d = mean_g[:, None, :] - pos[None, usable, :]  # (G, K, 2)
    s = cov_g[:, None] + cov[None, usable]  # (G, K, 2, 2)
    m2 = _mahalanobis2_2x2(d, s)
    cost = np.where(np.isfinite(m2) & (m2 <= gate), m2, _FORBIDDEN)
    if cost.shape[0] == 1 or cost.shape[1] == 1:  # one group or one detection: the cheapest
        best = int(np.argmin(cost))
        rows, cols = np.unravel_index([best], cost.shape)
    else:
        rows, cols = linear_sum_assignment(cost)
    good = cost[rows, cols] < _FORBIDDEN
    # A group takes at most one detection per node.
    assigned[usable[cols[good]]] = cand[rows[good]]
    return assigned


def _associate_singles(counts, pos_all, cov_all, info_all, gate) -> FrameAssociation:
    """:func:`associate_frame` when every node has at most one detection and
    every detection a regular covariance (one target in view, the common
    case): the same steps on Python floats, no array work per node."""
    n_nodes = len(counts)
    members: list[list[int]] = []
    info: list[list[float]] = []   # (a, b, c, d) of [[a, b], [c, d]], summed information
    eta: list[list[float]] = []
    for row, (n, (px, py), ((sa, sb), (sc, sd)), ((ia, ib), (ic, id_))) in enumerate(zip(
            np.flatnonzero(np.asarray(counts) > 0).tolist(), pos_all.tolist(), cov_all.tolist(),
            info_all.tolist())):
        best, best_m2 = -1, math.inf
        for g in range(len(info)):
            m2 = group_distance2(info[g] + eta[g], px, py, sa, sb, sc, sd)
            if m2 <= gate and m2 < best_m2:
                best, best_m2 = g, m2
        if best < 0:
            members.append([-1] * n_nodes)
            info.append([0.0, 0.0, 0.0, 0.0])
            eta.append([0.0, 0.0])
            best = len(members) - 1
        members[best][n] = 0
        a, b, c, d = info[best]
        info[best] = [a + ia, b + ib, c + ic, d + id_]
        eta[best] = [eta[best][0] + ia * px + ib * py, eta[best][1] + ic * px + id_ * py]
    cov_g = _inv_2x2(np.array(info).reshape(-1, 2, 2))
    cov_g = 0.5 * (cov_g + np.swapaxes(cov_g, -1, -2))
    return FrameAssociation(members=np.asarray(members, dtype=np.int64),
                            position_m=np.einsum("gij,gj->gi", cov_g, np.array(eta)),
                            covariance_m2=cov_g)


def _scatter(pos: NDArray, info: NDArray) -> tuple[NDArray, float]:
    """``(leave-one-out squared distances (k,), scatter)`` of a subset of
    detections: each member's distance to the others' fused position (their
    covariances summed), and ``sum (p_i - mean)' I_i (p_i - mean)``."""
    total = info.sum(axis=0)
    eta = np.einsum("kij,kj->ki", info, pos)
    mean = _inv_2x2(total) @ eta.sum(axis=0)
    d = pos - mean
    scatter = float(np.einsum("ki,kij,kj->", d, info, d))
    rest = total[None] - info
    m = np.einsum("kij,kj->ki", _inv_2x2(rest), eta.sum(axis=0)[None] - eta)
    return _mahalanobis2_2x2(pos - m, _inv_2x2(rest) + _inv_2x2(info)), scatter


def _largest_subset(left: list[int], pos, info, gate) -> list[int]:
    """Of the detections ``left``, the largest subset whose every member is
    within the gate of the others' fused position, of least scatter among
    those of its size (every subset tried)."""
    best: tuple[list[int], float] | None = None
    for size in range(len(left), 1, -1):
        for sub in combinations(left, size):
            idx = list(sub)
            loo, scatter = _scatter(pos[idx], info[idx])
            if np.all(loo <= gate) and (best is None or scatter < best[1]):
                best = (idx, scatter)
        if best is not None:
            return best[0]
    return [left[0]]


def _drop_worst(left: list[int], pos, info, gate) -> list[int]:
    """Of the detections ``left`` (more than :data:`MAX_SUBSET_NODES`), the
    subset left once the member farthest from the others' fused position is
    dropped, again and again, until every member is within the gate."""
    cur = list(left)
    while len(cur) > 1:
        loo, _ = _scatter(pos[cur], info[cur])
        loo = np.nan_to_num(loo, nan=np.inf)
        if np.all(loo <= gate):
            return cur
        cur.pop(int(np.argmax(loo)))
    return cur


def _best_subsets(counts, pos, info, gate) -> FrameAssociation:
    """:func:`associate_frame` of a frame with one detection per node at
    most that the nodes taken in order split: order-independent instead.
    Taken in order, a ghost of the first node may take the second node's
    detection and leave the third's, which agrees with the second, on its
    own. The group is the largest subset of detections whose every member is
    within the gate of the others' fused position, of least scatter among
    those of its size (:func:`_largest_subset`; :func:`_drop_worst` for
    more than :data:`MAX_SUBSET_NODES`); the rest are grouped alike."""
    nodes = np.flatnonzero(np.asarray(counts) > 0)
    left = list(range(nodes.size))
    members: list[list[int]] = []
    while left:
        chosen = (_largest_subset(left, pos, info, gate) if len(left) <= MAX_SUBSET_NODES
                  else _drop_worst(left, pos, info, gate))
        row = [-1] * len(counts)
        for i in chosen:
            row[nodes[i]] = 0
        members.append(row)
        left = [i for i in left if i not in chosen]
    members.sort(key=lambda r: [n for n, k in enumerate(r) if k >= 0][0])
    m = np.asarray(members, dtype=np.int64)
    used = (m >= 0)[:, nodes]                                   # (G, K) detections per group
    info_g = np.einsum("gk,kij->gij", used, info)
    eta_g = np.einsum("gk,kij,kj->gi", used, info, pos)
    cov_g = _inv_2x2(info_g)
    cov_g = 0.5 * (cov_g + np.swapaxes(cov_g, -1, -2))
    return FrameAssociation(members=m, position_m=np.einsum("gij,gj->gi", cov_g, eta_g),
                            covariance_m2=cov_g)


def group_distance2(group: Sequence[float], px: float, py: float,
                    sa: float, sb: float, sc: float, sd: float) -> float:
    """Squared Mahalanobis distance between a group's fused position and a
    detection, in floats: ``group`` the group's summed position information
    ``[[a, b], [c, d]]`` and information vector ``(e0, e1)`` as ``(a, b, c,
    d, e0, e1)``, the detection's position ``(px, py)`` and covariance
    ``[[sa, sb], [sc, sd]]``; the distance uses the sum of the two
    covariances (inf when it is not positive definite)."""
    a, b, c, d, e0, e1 = group
    det = a * d - b * c
    ga, gb, gc, gd = d / det, -b / det, -c / det, a / det   # the group's covariance
    dx = ga * e0 + gb * e1 - px
    dy = gc * e0 + gd * e1 - py
    qa, qb, qc, qd = ga + sa, gb + sb, gc + sc, gd + sd
    det_q = qa * qd - qb * qc
    if not det_q > 0:
        return math.inf
    return (qd * dx * dx - (qb + qc) * dx * dy + qa * dy * dy) / det_q


def associate_frame(
    measurements: Sequence[ArrayLike],
    node_poses: ArrayLike,
    noise: MeasurementNoise | Sequence[MeasurementNoise] = MeasurementNoise(),
    *,
    gate_probability: float = 0.999,
) -> FrameAssociation:
    """Group one frame's detections of ``N`` nodes into targets.

    Parameters
    ----------
    measurements : sequence of N arrays (K_n, 3)
        Each node's detections ``(range_m, omega_rad, doppler_mps)`` this frame
        (K_n may be 0).
    node_poses : (N, 3) float
        Calibrated poses in the global frame.
    noise : MeasurementNoise or sequence of N MeasurementNoise
        Measurement sigmas (default the paper's), one for every node or one
        per node (docs/CONVENTIONS.md, "Per-node noise"); each node's set its
        detections' position covariances and so the gate.
    gate_probability : float
        Probability mass inside the gate (chi-square, 2 dof) of two detections
        of the same target.

    Returns
    -------
    FrameAssociation
        Groups in order of creation: the first node's detections first. A
        detection whose position covariance is degenerate
        (:func:`detection_information`: range 0, a tiny range or tiny
        sigmas) gets a group of its own, with its position and (singular)
        covariance as they are; the fusion then flags it.
    """
    poses = check_finite(as_float_array(node_poses, "node_poses"), "node_poses")
    if poses.ndim != 2 or poses.shape[1] != 3:
        raise ValidationError(f"node_poses must have shape (N, 3), got {poses.shape}")
    if len(measurements) != poses.shape[0]:
        raise ValidationError(
            f"measurements has {len(measurements)} nodes but node_poses has {poses.shape[0]}"
        )
    noise = check_node_noise(noise, poses.shape[0])
    gate = gate_threshold(gate_probability)
    groups = _Groups(poses.shape[0])
    zs = []
    for n in range(poses.shape[0]):
        z = check_finite(as_float_array(measurements[n], f"measurements[{n}]"), f"measurements[{n}]")
        if z.ndim != 2 or z.shape[1] != 3:
            raise ValidationError(f"measurements[{n}] must have shape (K, 3), got {z.shape}")
        zs.append(z)
    counts = [z.shape[0] for z in zs]
    if sum(counts) == 0:
        return groups.result()
    # Every node's detections mapped at once (one call each), then node by node.
    z_all = np.concatenate(zs)
    pose_rows = np.repeat(poses, counts, axis=0)
    with np.errstate(all="ignore"):
        pos_all = detection_to_global(z_all[:, 0], z_all[:, 1], pose_rows)
        if all(nz == noise[0] for nz in noise):  # one noise for every node: one call
            cov_all = detection_position_covariance(z_all[:, 0], z_all[:, 1], pose_rows, noise[0])
        else:  # per-node noise (docs/CONVENTIONS.md, "Per-node noise")
            cov_all = np.concatenate([detection_position_covariance(z[:, 0], z[:, 1], poses[n],
                                                                    noise[n])
                                      for n, z in enumerate(zs)])
    info_all, ok_all = detection_information(cov_all)
    if max(counts) == 1 and bool(np.all(ok_all)):  # one regular detection per node at most
        out = _associate_singles(counts, pos_all, cov_all, info_all, gate)
        if len(out) > 1:
            out = _best_subsets(counts, pos_all, info_all, gate)
        return out
    start = 0
    for n, k_n in enumerate(counts):
        if k_n == 0:
            continue
        sl = slice(start, start + k_n)
        start += k_n
        pos, cov, info, ok = pos_all[sl], cov_all[sl], info_all[sl], ok_all[sl]
        assigned = _assign(groups, pos, cov, ok, gate)
        for k in range(k_n):
            groups.add(int(assigned[k]), n, k, pos[k], cov[k], info[k], bool(ok[k]))
    return groups.result()
