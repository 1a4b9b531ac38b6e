"""The stream's association of one frame (docs/STREAMING.md): the decisions
of :func:`mmsnap_graph.fusion.association.associate_frame`, with a fast path.

When every node has at most one detection (one target in view, the common
case of a live network) :class:`StreamAssociator` does what
``associate_frame`` does on that frame (each detection mapped to the global
frame with its first-order position covariance, the nodes taken in order, a
detection joining the group of least squared Mahalanobis distance inside the
chi-square gate, else starting its own) in plain Python floats, with each
node's pose and sigmas prepared once. It returns only the groups' members,
which is all the stream needs. Any other frame (several detections at a node,
or a degenerate detection covariance) goes to ``associate_frame`` itself.
``tests/fusion/stream/test_association.py`` checks the members against
``associate_frame`` on random frames.
"""

from __future__ import annotations

import math
from itertools import permutations
from typing import Sequence

import numpy as np
from numpy.typing import NDArray

from factors.models import DETECTION_MIN_COS

from ...data.noise import MeasurementNoise
from ..association import (MAX_CONDITION, MIN_VARIANCE_M2, associate_frame, gate_threshold,
                          group_distance2)

__all__ = ["StreamAssociator"]

_PI = math.pi
# Cost of a forbidden pair (as association's) and the most detections per node
# and groups the fast path enumerates assignments for.
_FORBIDDEN = 1e12
_MAX_DETECTIONS = 4


class StreamAssociator:
    """Association of one network's frames.

    node_poses : (N, 3) float, validated; noises : N :class:`MeasurementNoise`
    (node order); gate_probability : in (0, 1).
    """

    def __init__(self, node_poses: NDArray, noises: Sequence[MeasurementNoise],
                 gate_probability: float) -> None:
        self.node_poses = np.asarray(node_poses, dtype=float)
        self.noises = tuple(noises)
        self.gate_probability = float(gate_probability)
        self._gate = gate_threshold(gate_probability)
        self._nodes = [(px, py, math.cos(phi), math.sin(phi), m.range_m ** 2, m.omega_rad ** 2)
                       for (px, py, phi), m in zip(self.node_poses.tolist(), self.noises)]
        self._one_noise = all(m == self.noises[0] for m in self.noises)

    def members(self, per_node: Sequence[NDArray], rows: Sequence[list] | None = None) -> NDArray:
        """(G, N) int64: each node's detection row in each group, -1 where
        none. ``per_node``: N arrays (K_n, 3), validated; ``rows``: the same
        as lists (``tolist()``), when the caller has them."""
        if rows is None:
            rows = [z.tolist() for z in per_node]
        if all(len(r) <= 1 for r in rows):
            out = self._singles(rows)
        elif max(len(r) for r in rows) <= _MAX_DETECTIONS:
            out = self._several(rows)
        else:
            out = None
        if out is not None:
            return out
        noise = self.noises[0] if self._one_noise else self.noises
        return associate_frame(per_node, self.node_poses, noise,
                               gate_probability=self.gate_probability).members

    def _singles(self, rows) -> NDArray | None:
        """The members when every node has at most one detection and all fall
        in one group; None when they do not or a detection's covariance is
        degenerate (``associate_frame`` decides)."""
        n_nodes = len(rows)
        dets = []
        for n, r in enumerate(rows):
            if r:
                det = _detection(r[0][0], r[0][1], self._nodes[n])
                if det is None:
                    return None
                dets.append((n, det))
        if not dets:
            return np.zeros((0, n_nodes), dtype=np.int64)
        gate = self._gate
        members: list[list[int]] = []
        groups: list[list[float]] = []   # summed information (a, b, c, d) and eta (e0, e1)
        for n, (px, py, sa, sb, sc, sd, ia, ib, ic, id_) in dets:
            best, best_m2 = -1, math.inf
            for g, group in enumerate(groups):
                m2 = group_distance2(group, px, py, sa, sb, sc, sd)
                if m2 <= gate and m2 < best_m2:
                    best, best_m2 = g, m2
            if best < 0:
                members.append([-1] * n_nodes)
                groups.append([0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
            members[best][n] = 0
            a, b, c, d, e0, e1 = groups[best]
            groups[best] = [a + ia, b + ib, c + ic, d + id_,
                            e0 + ia * px + ib * py, e1 + ic * px + id_ * py]
        if len(members) > 1:  # split: associate_frame regroups it order-independently
            return None
        return np.array(members, dtype=np.int64)


    def _several(self, rows) -> NDArray | None:
        """The members when a node has several detections (``associate_frame``'s
        general path: each node's detections assigned to the groups so far by
        gated minimum-cost assignment); None when a detection's covariance is
        degenerate or there are more than ``_MAX_DETECTIONS`` groups."""
        n_nodes = len(rows)
        gate = self._gate
        members: list[list[int]] = []
        infos: list[list[float]] = []   # each group's summed information (a, b, c, d)
        etas: list[list[float]] = []
        for n, node_rows in enumerate(rows):
            if not node_rows:
                continue
            dets = [_detection(r[0], r[1], self._nodes[n]) for r in node_rows]
            if any(d is None for d in dets) or len(members) > _MAX_DETECTIONS:
                return None
            assigned = [-1] * len(dets)
            if members:
                cost = []
                for info, eta in zip(infos, etas):
                    mx, my, (ga, gb, gc, gd) = _group_mean(info, eta)
                    cost.append([_gated_m2(mx - px, my - py, ga + sa, gb + sb, gc + sc, gd + sd, gate)
                                 for px, py, sa, sb, sc, sd, *_ in dets])
                for g, k in _assignment(cost):
                    if cost[g][k] < _FORBIDDEN:
                        assigned[k] = g
            for k, (px, py, _, _, _, _, ia, ib, ic, id_) in enumerate(dets):
                g = assigned[k]
                if g < 0:
                    members.append([-1] * n_nodes)
                    infos.append([0.0, 0.0, 0.0, 0.0])
                    etas.append([0.0, 0.0])
                    g = len(members) - 1
                members[g][n] = k
                a, b, c, d = infos[g]
                infos[g] = [a + ia, b + ib, c + ic, d + id_]
                etas[g] = [etas[g][0] + ia * px + ib * py, etas[g][1] + ic * px + id_ * py]
        return np.array(members, dtype=np.int64).reshape(-1, n_nodes)


def _scaled(a, b, c, d):
    """``(a, b, c, d) / scale, det, scale`` of a 2x2 matrix as
    ``association``'s scaled closed forms take it."""
    scale = max(abs(a), abs(b), abs(c), abs(d))
    if not (scale > 0.0 and math.isfinite(scale)):
        scale = 1.0
    a, b, c, d = a / scale, b / scale, c / scale, d / scale
    return a, b, c, d, a * d - b * c, scale


def _group_mean(info, eta):
    """A group's mean and covariance ``(mx, my, (a, b, c, d))`` from its summed
    information and information vector (``association._inv_2x2``)."""
    a, b, c, d, det, scale = _scaled(*info)
    f = det * scale
    if f == 0.0:  # singular (numpy gives inf and NaN, and no pair passes the gate)
        return math.nan, math.nan, (math.nan,) * 4
    ga, gb, gc, gd = d / f, -b / f, -c / f, a / f
    return ga * eta[0] + gb * eta[1], gc * eta[0] + gd * eta[1], (ga, gb, gc, gd)


def _gated_m2(dx, dy, a, b, c, d, gate) -> float:
    """The squared Mahalanobis distance, or ``_FORBIDDEN`` beyond the gate or
    where ``S`` is singular (``association._mahalanobis2_2x2``)."""
    a, b, c, d, det, scale = _scaled(a, b, c, d)
    try:
        m2 = (d * dx * dx - (b + c) * dx * dy + a * dy * dy) / (det * scale)
    except ZeroDivisionError:
        return _FORBIDDEN
    return m2 if math.isfinite(m2) and m2 <= gate else _FORBIDDEN


def _assignment(cost: list[list[float]]) -> list[tuple[int, int]]:
    """The (group, detection) pairs of least total cost, as
    ``association._assign`` picks them: the single cheapest pair for one group
    or one detection, else a full assignment of min(G, K) pairs (by
    enumeration: at most ``_MAX_DETECTIONS`` detections and groups)."""
    n_g, n_k = len(cost), len(cost[0])
    if n_g == 1 or n_k == 1:
        flat = [v for row in cost for v in row]
        best = flat.index(min(flat))
        return [divmod(best, n_k)]
    if n_g <= n_k:
        options = ((list(range(n_g)), list(cols)) for cols in permutations(range(n_k), n_g))
    else:
        options = ((list(rows), list(range(n_k))) for rows in permutations(range(n_g), n_k))
    best, best_cost = None, math.inf
    for rows, cols in options:
        total = 0.0
        for i, j in zip(rows, cols):
            total += cost[i][j]
        if total < best_cost:
            best, best_cost = (rows, cols), total
    return list(zip(*best))


def _detection(range_m: float, omega_rad: float, node) -> tuple[float, ...] | None:
    """``(x, y, covariance (a, b, c, d), information (a, b, c, d))`` of one
    detection in the global frame, as ``associate_frame`` computes them
    (:func:`factors.models.detection_to_global`,
    :func:`factors.models.detection_covariance_global`,
    :func:`~mmsnap_graph.fusion.association.detection_information`); None
    when the covariance is degenerate."""
    px, py, cp, sp, var_r, var_w = node
    st = min(max(omega_rad / _PI, -1.0), 1.0)
    ct = math.sqrt(1.0 - st * st)
    u, v = range_m * st, range_m * ct
    x, y = px + cp * u - sp * v, py + sp * u + cp * v
    # Local covariance J diag(var_r, var_w) J^T, J = [[st, k], [c, -k st / c]].
    c = max(ct, DETECTION_MIN_COS)
    k = range_m / _PI
    j11 = -k * st / c
    l00 = st * st * var_r + k * k * var_w
    l01 = st * c * var_r + k * j11 * var_w
    l11 = c * c * var_r + j11 * j11 * var_w
    # Rotated into the global frame: R l R^T.
    r00, r01 = cp * l00 - sp * l01, cp * l01 - sp * l11
    r10, r11 = sp * l00 + cp * l01, sp * l01 + cp * l11
    sa, sb = r00 * cp - r01 * sp, r00 * sp + r01 * cp
    sc, sd = r10 * cp - r11 * sp, r10 * sp + r11 * cp
    info = _information(sa, sb, sc, sd)
    if info is None:
        return None
    return (x, y, sa, sb, sc, sd) + info


def _information(sa, sb, sc, sd) -> tuple[float, float, float, float] | None:
    """The inverse of a detection covariance, None where
    :func:`~mmsnap_graph.fusion.association.detection_information` finds it
    degenerate (not finite, smallest eigenvalue at most ``MIN_VARIANCE_M2``
    or ``1 / MAX_CONDITION`` of the largest); the same scaled closed forms."""
    if not all(map(math.isfinite, (sa, sb, sc, sd))):
        return None
    off = 0.5 * (sb + sc)
    scale = max(abs(sa), abs(off), abs(sd))
    if not scale > 0.0:
        scale = 1.0
    a, b, d = sa / scale, off / scale, sd / scale
    det = a * d - b * b
    big = 0.5 * (a + d) + math.hypot(0.5 * (a - d), b)
    small = det / big if big > 0 else -math.inf
    if not (small * scale > MIN_VARIANCE_M2 and small * MAX_CONDITION > big):
        return None
    f = det * scale
    return d / f, -b / f, -b / f, a / f
