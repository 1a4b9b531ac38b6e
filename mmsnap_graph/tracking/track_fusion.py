"""Track-level fusion, the paper's benchmark (docs/CONVENTIONS.md, "Track-level fusion (the paper's benchmark)").

Each node's EKF tracks (:class:`~mmsnap_graph.data.recording.Tracks`, the node's
local frame) are moved into the global frame with the node's calibrated pose:
``p = p_i + R(phi_i) p_local``, ``v = R(phi_i) v_local`` and
``P = T P_local T^T`` with ``T = blkdiag(R, R)`` (every covariance block
rotated). Tracks of two nodes on the same target in the same frame are then
fused by covariance intersection,

.. math::

    P^{-1} = \\omega P_1^{-1} + (1 - \\omega) P_2^{-1}, \\qquad
    P^{-1} x = \\omega P_1^{-1} x_1 + (1 - \\omega) P_2^{-1} x_2,

with ``omega`` in ``[0, 1]`` minimizing ``trace(P)`` (a convex function of
``omega``; golden-section search, vectorized over frames).

Which track of S2 goes with which of S1 in a frame: a gated assignment on the
global positions (:func:`scipy.optimize.linear_sum_assignment` on the squared
Mahalanobis distance with ``P_1 + P_2``); with one track per node and frame
(single-target tracks) the gate alone decides, for all frames at once.
``gate_probability=None`` fuses without a gate (the demo's benchmark: each
node's one track of the one target).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import linear_sum_assignment

from .._linalg import chol_soa, from_soa, inverse_soa, solve_soa, to_soa
from ..errors import ValidationError
from ..data.recording import Tracks
from .._validation import as_float_array, check_finite, chi2_gate

__all__ = [
    "transform_tracks",
    "covariance_intersection",
    "TrackFusion",
    "fuse_tracks",
]

_GOLDEN = (np.sqrt(5.0) - 1.0) / 2.0


def _pose(pose: ArrayLike, name: str) -> NDArray:
    p = check_finite(as_float_array(pose, name), name)
    if p.shape != (3,):
        raise ValidationError(f"{name} must have shape (3,) (x_m, y_m, phi_rad), got {p.shape}")
    return p


def transform_tracks(state: ArrayLike, covariance: ArrayLike, node_pose: ArrayLike
                     ) -> tuple[NDArray, NDArray]:
    """Local-frame track states and covariances into the global frame.

    state : (K, 4) ``(x, y, vx, vy)`` in the node's frame; covariance : (K, 4, 4);
    node_pose : (3,) the node's ``(x_m, y_m, phi_rad)``.
    Returns ``state (K, 4)``, ``covariance (K, 4, 4)`` (symmetrized).
    """
    x = check_finite(as_float_array(state, "state"), "state")
    p = check_finite(as_float_array(covariance, "covariance"), "covariance")
    if x.ndim != 2 or x.shape[1] != 4 or p.shape != (x.shape[0], 4, 4):
        raise ValidationError(f"state (K, 4) and covariance (K, 4, 4) disagree: {x.shape} and {p.shape}")
    pose = _pose(node_pose, "node_pose")
    c, s = np.cos(pose[2]), np.sin(pose[2])
    rot = np.array([[c, -s], [s, c]])
    t = np.zeros((4, 4))
    t[:2, :2] = rot
    t[2:, 2:] = rot
    out = x @ t.T
    out[:, :2] += pose[:2]
    cov = t @ p @ t.T
    return out, 0.5 * (cov + np.swapaxes(cov, -1, -2))


def covariance_intersection(x1: ArrayLike, p1: ArrayLike, x2: ArrayLike, p2: ArrayLike, *,
                            tolerance: float = 1e-10) -> tuple[NDArray, NDArray, NDArray]:
    """Covariance intersection with the trace-minimizing weight, per row.

    x1, x2 : (K, n); p1, p2 : (K, n, n) positive definite.
    Returns ``x (K, n)``, ``P (K, n, n)`` and ``omega (K,)`` (the weight of
    the first estimate), ``omega`` found to ``tolerance`` by golden-section
    search on ``[0, 1]``.
    """
    x1 = check_finite(as_float_array(x1, "x1"), "x1")
    x2 = check_finite(as_float_array(x2, "x2"), "x2")
    p1 = check_finite(as_float_array(p1, "p1"), "p1")
    p2 = check_finite(as_float_array(p2, "p2"), "p2")
    if x1.ndim != 2 or x1.shape != x2.shape or p1.shape != x1.shape + (x1.shape[1],) or p2.shape != p1.shape:
        raise ValidationError(f"x1, x2 (K, n) and p1, p2 (K, n, n) disagree: {x1.shape}, {x2.shape}, "
                              f"{p1.shape}, {p2.shape}")
    info1 = []
    info2 = []
    for p, store, name in ((p1, info1, "p1"), (p2, info2, "p2")):
        lo, ok = chol_soa(to_soa(p))
        if not np.all(ok):
            raise ValidationError(f"{name} must be positive definite (row {int(np.argmin(ok))} is not)")
        store.append(inverse_soa(lo))
    a_t, b_t = info1[0], info2[0]  # (n, n, K) information matrices

    def trace_of_inverse(w):
        lo, ok = chol_soa(w * a_t + (1.0 - w) * b_t)
        inv = inverse_soa(lo)
        return np.einsum("iik->k", inv)

    k = x1.shape[0]
    lo_w = np.zeros(k)
    hi_w = np.ones(k)
    c = hi_w - _GOLDEN * (hi_w - lo_w)
    d = lo_w + _GOLDEN * (hi_w - lo_w)
    fc, fd = trace_of_inverse(c), trace_of_inverse(d)
    n_iter = int(np.ceil(np.log(tolerance) / np.log(_GOLDEN)))
    for _ in range(n_iter):
        left = fc < fd  # the minimum lies in [lo, d]
        hi_w = np.where(left, d, hi_w)
        lo_w = np.where(left, lo_w, c)
        new_c = hi_w - _GOLDEN * (hi_w - lo_w)
        new_d = lo_w + _GOLDEN * (hi_w - lo_w)
        # Reuse the surviving interior point, evaluate the new one.
        c_next = np.where(left, new_c, d)
        d_next = np.where(left, c, new_d)
        f_new = trace_of_inverse(np.where(left, new_c, new_d))
        fc, fd = np.where(left, f_new, fd), np.where(left, fc, f_new)
        c, d = c_next, d_next
    w = 0.5 * (lo_w + hi_w)
    # The ends: CI may pick one estimate alone.
    f_w, f0, f1 = trace_of_inverse(w), trace_of_inverse(np.zeros(k)), trace_of_inverse(np.ones(k))
    w = np.where(f0 < f_w, 0.0, w)
    w = np.where((f1 < f_w) & (f1 <= f0), 1.0, w)
    info = w * a_t + (1.0 - w) * b_t
    eta = (w * np.einsum("ijk,kj->ik", a_t, x1) + (1.0 - w) * np.einsum("ijk,kj->ik", b_t, x2))
    lo, _ = chol_soa(info)
    x = solve_soa(lo, eta).T
    p = from_soa(inverse_soa(lo))
    return x, p, w


@dataclass(frozen=True, kw_only=True, slots=True)
class TrackFusion:
    """Fused tracks of two nodes, one row per fused pair per frame, global frame.

    frame : (K,) int; track_id_1, track_id_2 : (K,) the nodes' track ids;
    state : (K, 4); covariance : (K, 4, 4); omega : (K,) the CI weight of node 1.
    """

    frame: NDArray
    track_id_1: NDArray
    track_id_2: NDArray
    state: NDArray
    covariance: NDArray
    omega: NDArray

    def __len__(self) -> int:
        return int(self.frame.shape[0])

    def as_tracks(self) -> Tracks:
        """As :class:`Tracks` with ``track_id = 1000 * track_id_1 + track_id_2``
        (one id per pair of node tracks)."""
        return Tracks(frame=self.frame, track_id=1000 * self.track_id_1 + self.track_id_2,
                      state=self.state, covariance=self.covariance)


def fuse_tracks(tracks_1: Tracks, pose_1: ArrayLike, tracks_2: Tracks, pose_2: ArrayLike, *,
                gate_probability: float | None = 0.9999) -> TrackFusion:
    """Track-level fusion of two nodes' EKF tracks (the paper's benchmark).

    tracks_1, tracks_2 : each node's tracks in its local frame.
    pose_1, pose_2 : (3,) their calibrated poses (S1's is normally zero).
    gate_probability : chi-square gate (2 dof) on the global positions;
        ``None``: no gate (every pair may be fused; with one track per node
        and frame, every frame both nodes have is fused).
    Returns the fused pairs of every frame both nodes have tracks in, in
    increasing frame order.
    """
    if not isinstance(tracks_1, Tracks) or not isinstance(tracks_2, Tracks):
        raise ValidationError("tracks_1 and tracks_2 must be Tracks")
    if gate_probability is None:
        gate = np.inf
    elif not 0.0 < gate_probability < 1.0:
        raise ValidationError(f"gate_probability must be in (0, 1) or None, got {gate_probability!r}")
    else:
        gate = chi2_gate(gate_probability, 2)
    x1, p1 = transform_tracks(tracks_1.state, tracks_1.covariance, pose_1)
    x2, p2 = transform_tracks(tracks_2.state, tracks_2.covariance, pose_2)
    if _one_row_per_frame(tracks_1.frame) and _one_row_per_frame(tracks_2.frame):
        rows_1, rows_2 = _pair_single_rows(tracks_1.frame, x1, p1, tracks_2.frame, x2, p2, gate)
    else:
        rows_1, rows_2 = _pair_by_assignment(tracks_1.frame, x1, p1, tracks_2.frame, x2, p2, gate)
    if rows_1.size == 0:
        return TrackFusion(frame=np.zeros(0, np.int64), track_id_1=np.zeros(0, np.int64),
                           track_id_2=np.zeros(0, np.int64), state=np.zeros((0, 4)),
                           covariance=np.zeros((0, 4, 4)), omega=np.zeros(0))
    x, p, w = covariance_intersection(x1[rows_1], p1[rows_1], x2[rows_2], p2[rows_2])
    return TrackFusion(frame=tracks_1.frame[rows_1], track_id_1=tracks_1.track_id[rows_1],
                       track_id_2=tracks_2.track_id[rows_2], state=x, covariance=p, omega=w)


def _one_row_per_frame(frame: NDArray) -> bool:
    return bool(np.unique(frame).size == frame.size)


def _squared_mahalanobis(x1: NDArray, p1: NDArray, x2: NDArray, p2: NDArray) -> NDArray:
    """Squared Mahalanobis distance of the positions, ``(..., 4)`` states and
    ``(..., 4, 4)`` covariances broadcast against each other."""
    d = x1[..., :2] - x2[..., :2]
    s = p1[..., :2, :2] + p2[..., :2, :2]
    return np.einsum("...i,...i->...", d, np.linalg.solve(s, d[..., None])[..., 0])


def _pair_single_rows(f1: NDArray, x1: NDArray, p1: NDArray, f2: NDArray, x2: NDArray,
                      p2: NDArray, gate: float) -> tuple[NDArray, NDArray]:
    """At most one track per node and frame: the pair of each common frame,
    kept when inside the gate (vectorized; what the assignment gives there)."""
    common, rows_1, rows_2 = np.intersect1d(f1, f2, assume_unique=True, return_indices=True)
    if common.size and np.isfinite(gate):
        inside = _squared_mahalanobis(x1[rows_1], p1[rows_1], x2[rows_2], p2[rows_2]) <= gate
        rows_1, rows_2 = rows_1[inside], rows_2[inside]
    return rows_1.astype(np.int64), rows_2.astype(np.int64)


def _pair_by_assignment(f1: NDArray, x1: NDArray, p1: NDArray, f2: NDArray, x2: NDArray,
                        p2: NDArray, gate: float) -> tuple[NDArray, NDArray]:
    """Several tracks per node and frame: a gated assignment per frame."""
    common = np.intersect1d(f1, f2)
    rows_1, rows_2 = [], []
    o1 = np.argsort(f1, kind="stable")
    o2 = np.argsort(f2, kind="stable")
    f1s, f2s = f1[o1], f2[o2]
    for f in common:
        a = o1[np.searchsorted(f1s, f):np.searchsorted(f1s, f, side="right")]
        b = o2[np.searchsorted(f2s, f):np.searchsorted(f2s, f, side="right")]
        m2 = _squared_mahalanobis(x1[a][:, None], p1[a][:, None], x2[b][None], p2[b][None])
        cost = np.where(m2 <= gate, m2, 1e12)
        r, c = linear_sum_assignment(cost)
        ok = cost[r, c] < 1e12
        rows_1.extend(a[r[ok]])
        rows_2.extend(b[c[ok]])
    return np.asarray(rows_1, dtype=np.int64), np.asarray(rows_2, dtype=np.int64)
