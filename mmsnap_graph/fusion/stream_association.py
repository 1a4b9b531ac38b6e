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
``tests/test_stream_fast_path.py`` checks the members against
``associate_frame`` on random frames.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np
from numpy.typing import NDArray

from factors.models import DETECTION_MIN_COS

from ..data.noise import MeasurementNoise
from .association import MAX_CONDITION, MIN_VARIANCE_M2, associate_frame, gate_threshold

__all__ = ["StreamAssociator"]

_PI = math.pi


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
            if out is not None:
                return out
        noise = self.noises[0] if self._one_noise else self.noises
        return associate_frame(per_node, self.node_poses, noise,
                               gate_probability=self.gate_probability).members

    def _singles(self, rows) -> NDArray | None:
        """The members when every node has at most one detection; None when a
        detection's covariance is degenerate (``associate_frame`` decides)."""
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
            for g, (a, b, c, d, e0, e1) in enumerate(groups):
                det = a * d - b * c
                ga, gb, gc, gd = d / det, -b / det, -c / det, a / det   # the group's covariance
                mx, my = ga * e0 + gb * e1, gc * e0 + gd * e1
                dx, dy = mx - px, my - py
                qa, qb, qc, qd = ga + sa, gb + sb, gc + sc, gd + sd
                det_q = qa * qd - qb * qc
                m2 = (qd * dx * dx - (qb + qc) * dx * dy + qa * dy * dy) / det_q if det_q > 0 \
                    else math.inf
                if m2 <= gate and m2 < best_m2:
                    best, best_m2 = g, m2
            if best < 0:
                members.append([-1] * n_nodes)
                groups.append([0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
            members[best][n] = 0
            a, b, c, d, e0, e1 = groups[best]
            groups[best] = [a + ia, b + ib, c + ic, d + id_,
                            e0 + ia * px + ib * py, e1 + ic * px + id_ * py]
        return np.array(members, dtype=np.int64)


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
