"""Every node's pose at once from the matched track points of all node pairs.

Pairwise closed forms that reuse one node's detections (S1-S2 and S1-S3 both
use S1's track) are correlated; a pose graph that takes them as independent
edges counts S1's track twice and reports covariances that are too small
(docs/CALIBRATION.md, "Network: all poses from the matched points"). Here the
poses are solved jointly from the points themselves:

.. math::

    \\min_{T_2..T_N} \\sum_{(a, b)} \\sum_k |T_a(z_a[k]) - T_b(z_b[k])|^2,

``T_1`` the identity (the reference), ``z_a[k]``, ``z_b[k]`` the matched
points of the edge a-b at a's frame ``k`` (and b's ``k + lag``), residuals in
the reference frame. Gauss-Newton in GTSAM's body tangent of each pose
(``d T(z) / d xi = R [I, J z]``,
:func:`~mmsnap_graph.calibration.pairwise.closed_form.alignment_jacobian`), started
from the composed pairwise poses. For two nodes this is the closed form.

Covariance: the sandwich ``H^{-1} Omega H^{-1}``, ``H = sum J^T J``, with the
scores ``J^T r`` of all residuals of one instant (one frame on the reference's
clock: every edge that uses the same detection) summed before their outer
product, so that shared detections are counted once (a cluster-robust
sandwich), times ``n / (n - p)`` (``n`` instants, ``p`` unknowns); then
multiplied by the integrated autocorrelation time of that score series
(:func:`~mmsnap_graph.calibration.pairwise.effective_samples.autocorrelation_factor`) for
tracks whose errors are correlated from frame to frame.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from .closed_form import alignment_jacobian
from .effective_samples import autocorrelation_factor
from ..poses import pose_array, to_pose2

__all__ = ["PointEdge", "PointGraphSolution", "solve_point_graph", "STEP_TOLERANCE"]

#: Gauss-Newton stops when every step is below this fraction of its pose's
#: sigma: further steps move the poses by nothing the covariance can see.
#: (With noisy tracks the residuals are large against the lever arms and
#: Gauss-Newton converges linearly, about 0.15 per step on 10 nodes.)
STEP_TOLERANCE = 1e-3


@dataclass(frozen=True, kw_only=True, slots=True)
class PointEdge:
    """Matched points of one node pair: ``points_a_m[k]`` in a's frame and
    ``points_b_m[k]`` in b's are one target at the reference-clock time
    ``times[k]``."""

    node_a: str
    node_b: str
    points_a_m: NDArray
    points_b_m: NDArray
    times: NDArray


@dataclass(frozen=True, kw_only=True, slots=True)
class PointGraphSolution:
    """poses : name -> (3,); covariance : (3M, 3M) joint covariance of the M
    non-reference poses in ``order``; autocorrelation_factor : tau used;
    iterations, cost_m2 (sum of squared residuals), converged."""

    poses: Mapping[str, NDArray]
    order: tuple[str, ...]
    covariance: NDArray
    autocorrelation_factor: float
    iterations: int
    cost_m2: float
    converged: bool


def _transform(pose: NDArray, pts: NDArray) -> NDArray:
    c, s = np.cos(pose[2]), np.sin(pose[2])
    return np.stack([pose[0] + c * pts[:, 0] - s * pts[:, 1],
                     pose[1] + s * pts[:, 0] + c * pts[:, 1]], axis=-1)


def _edge_terms(poses, index, e):
    """One edge's residuals (k, 2) and its Jacobian blocks ``[(column,
    (k, 2, 3))]`` (a's ``+A_a``, b's ``-A_b``; the reference has none)."""
    r = _transform(poses[e.node_a], e.points_a_m) - _transform(poses[e.node_b], e.points_b_m)
    blocks = []
    if e.node_a in index:
        blocks.append((index[e.node_a], alignment_jacobian(poses[e.node_a], e.points_a_m)))
    if e.node_b in index:
        blocks.append((index[e.node_b], -alignment_jacobian(poses[e.node_b], e.points_b_m)))
    return r, blocks


def _normal_equations(poses, index, edges, p):
    """``H = sum J^T J`` (p, p), ``J^T r`` (p,), the cost ``sum |r|^2`` and
    the number of rows, per edge in 3x3 blocks (the Jacobian of a row has
    two nonzero blocks: no dense (n, 2, p) array)."""
    h = np.zeros((p, p))
    grad = np.zeros(p)
    cost, rows = 0.0, 0
    for e in edges:
        r, blocks = _edge_terms(poses, index, e)
        cost += float(np.sum(r * r))
        rows += r.shape[0]
        for i, ji in blocks:
            grad[i:i + 3] += np.einsum("kia,ki->a", ji, r)
            for j, jj in blocks:
                h[i:i + 3, j:j + 3] += np.einsum("kia,kib->ab", ji, jj)
    return h, grad, cost, rows


def _rot(phi: float) -> NDArray:
    c, s = np.cos(phi), np.sin(phi)
    return np.array([[c, -s], [s, c]])


_J = np.array([[0.0, -1.0], [1.0, 0.0]])


def _moments(e: PointEdge) -> tuple:
    """Sums of one edge's points that the normal equations need: ``K``,
    ``sum z_a``, ``sum z_b``, ``sum |z_a|^2``, ``sum |z_b|^2``,
    ``M = sum z_a z_b^T``."""
    a, b = e.points_a_m, e.points_b_m
    return (a.shape[0], a.sum(axis=0), b.sum(axis=0), float(np.sum(a * a)),
            float(np.sum(b * b)), a.T @ b)


def _moment_blocks(pa, pb, mom):
    """``H_aa``, ``H_bb``, ``H_ab`` (3x3) and ``g_a``, ``g_b`` (3,) of one edge
    from its moments: the same sums as :func:`_normal_equations` (tested
    equal), without touching the rows. ``R^T R = I`` and ``J^T X J = X`` for
    a rotation ``X`` make every term a moment."""
    k, sa, sb, qa, qb, m = mom
    ra, rb = _rot(pa[2]), _rot(pb[2])
    rab = ra.T @ rb
    dp = pa[:2] - pb[:2]
    jsa, jsb = _J @ sa, _J @ sb
    h_aa = np.block([[k * np.eye(2), jsa[:, None]], [jsa[None, :], np.array([[qa]])]])
    h_bb = np.block([[k * np.eye(2), jsb[:, None]], [jsb[None, :], np.array([[qb]])]])
    h_ab = -np.block([[k * rab, (rab @ jsb)[:, None]],
                      [(jsa @ rab)[None, :], np.array([[np.trace(rab @ m.T)]])]])
    d_a = ra.T @ dp
    ga_t = sa + k * d_a - rab @ sb
    ga_r = jsa @ d_a - np.trace(_J.T @ rab @ m.T)
    d_b = rb.T @ dp
    gb_t = rab.T @ sa + k * d_b - sb
    gb_r = np.trace(_J.T @ rab.T @ m) + jsb @ d_b
    cost = (qa + qb + k * dp @ dp + 2.0 * dp @ (ra @ sa) - 2.0 * dp @ (rb @ sb)
            - 2.0 * np.trace(rab @ m.T))
    return h_aa, h_bb, h_ab, np.append(ga_t, ga_r), -np.append(gb_t, gb_r), cost


def _moment_equations(poses, index, edges, moments, p):
    """:func:`_normal_equations` from the edges' moments (unweighted)."""
    h = np.zeros((p, p))
    grad = np.zeros(p)
    cost, rows = 0.0, 0
    for e, mom in zip(edges, moments):
        h_aa, h_bb, h_ab, g_a, g_b, c = _moment_blocks(poses[e.node_a], poses[e.node_b], mom)
        cost += c
        rows += mom[0]
        i, j = index.get(e.node_a), index.get(e.node_b)
        if i is not None:
            h[i:i + 3, i:i + 3] += h_aa
            grad[i:i + 3] += g_a
        if j is not None:
            h[j:j + 3, j:j + 3] += h_bb
            grad[j:j + 3] += g_b
        if i is not None and j is not None:
            h[i:i + 3, j:j + 3] += h_ab
            h[j:j + 3, i:i + 3] += h_ab.T
    return h, grad, max(cost, 0.0), rows


def _gauss_newton(poses, index, edges, p, max_iterations):
    """Gauss-Newton on the body tangents; returns the poses, iterations and
    whether the last step was below :data:`STEP_TOLERANCE` of every pose
    sigma (the residual-variance estimate ``s^2 H^{-1}``)."""
    converged = False
    it = 0
    moments = [_moments(e) for e in edges]
    for it in range(1, max_iterations + 1):
        h, grad, cost, rows = _moment_equations(poses, index, edges, moments, p)
        h_inv = np.linalg.inv(h)
        step = -h_inv @ grad
        for n, i in index.items():
            poses[n] = pose_array(to_pose2(poses[n]).retract(step[i:i + 3]))
        sigma = np.sqrt(np.maximum(np.diag(h_inv) * cost / max(2 * rows - p, 1), 1e-300))
        if np.all(np.abs(step) < STEP_TOLERANCE * sigma):
            converged = True
            break
    return poses, it, converged


def _covariance(poses, index, edges, p, autocorrelation):
    """Cluster-robust sandwich (module doc) and the autocorrelation factor."""
    h = _normal_equations(poses, index, edges, p)[0]
    uniq = np.unique(np.concatenate([e.times for e in edges]))
    clustered = np.zeros((uniq.size, p))
    cost = 0.0
    for e in edges:
        r, blocks = _edge_terms(poses, index, e)
        cost += float(np.sum(r * r))
        slot = np.searchsorted(uniq, e.times)
        for i, ji in blocks:
            np.add.at(clustered[:, i:i + 3], slot, np.einsum("kia,ki->ka", ji, r))
    n = uniq.size
    meat = clustered.T @ clustered * (n / max(n - p, 1))
    h_inv = np.linalg.inv(h)
    tau = autocorrelation_factor(clustered, uniq) if autocorrelation else 1.0
    cov = h_inv @ meat @ h_inv * tau
    return 0.5 * (cov + cov.T), tau, cost


def solve_point_graph(
    reference: str,
    initial_poses: Mapping[str, NDArray],
    edges: Sequence[PointEdge],
    *,
    autocorrelation: bool = True,
    max_iterations: int = 20,
) -> PointGraphSolution:
    """Solve the poses of every node in ``initial_poses`` but ``reference``
    from the edges' matched points (module doc).

    initial_poses : name -> (3,) starting pose (the reference's is ignored:
        identity); every edge's nodes must be in it.
    Raises ``numpy.linalg.LinAlgError`` when the normal equations are
    singular (a caller turns it into ``success=False``).
    """
    order = tuple(n for n in initial_poses if n != reference)
    index = {n: 3 * i for i, n in enumerate(order)}
    p = 3 * len(order)
    poses = {n: np.asarray(v, dtype=float).copy() for n, v in initial_poses.items()}
    poses[reference] = np.zeros(3)
    poses, it, converged = _gauss_newton(poses, index, edges, p, max_iterations)
    cov, tau, cost = _covariance(poses, index, edges, p, autocorrelation)
    return PointGraphSolution(poses=poses, order=order, covariance=cov,
                              autocorrelation_factor=tau, iterations=it, cost_m2=cost,
                              converged=converged)
