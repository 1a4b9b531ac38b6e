"""Network-wide calibration: pairwise estimates stitched into a pose graph.

Each pairwise estimate (pose of node b in node a's frame, with its covariance
in the body-frame tangent of that relative pose) becomes a
``gtsam.BetweenFactorPose2(a, b, a_T_b, Gaussian(covariance))``: exactly the
coordinates in which GTSAM whitens a between factor's error, so the closed
form's covariance is the factor's noise without conversion. A tight prior
anchors the reference node (S1) at the origin; LM solves the graph, and
``gtsam.Marginals`` gives every other node's marginal pose covariance (the
reference's is zero by definition). Nodes with no path of edges to the
reference are reported in ``unreachable`` and get no pose.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Mapping, Sequence

import gtsam
import numpy as np
from numpy.typing import NDArray

from ..errors import ValidationError
from .._validation import as_float_array, check_finite, check_shape
from .closed_form import PairwiseCalibration
from .matching import LocalTracks, match_tracks
from .poses import pose_array, to_pose2

__all__ = ["PoseEdge", "PoseGraphCalibration", "pose_graph_calibration", "pairwise_edges"]

#: Sigma of the prior that anchors the reference node (m and rad): small
#: enough to be a constraint, large enough to keep the Cholesky well scaled.
ANCHOR_SIGMA = 1e-6


@dataclass(frozen=True, kw_only=True, slots=True)
class PoseEdge:
    """A relative pose measurement: ``pose`` of ``node_b`` in ``node_a``'s frame.

    pose : (3,); covariance : (3, 3) in the body tangent of ``pose``;
    rmse_m, n_frames, lag_frames : from the pairwise estimate (informative).
    """

    node_a: str
    node_b: str
    pose: NDArray
    covariance: NDArray
    rmse_m: float = float("nan")
    n_frames: int = 0
    lag_frames: int = 0

    def __post_init__(self) -> None:
        if self.node_a == self.node_b:
            raise ValidationError(f"an edge must join two nodes, got {self.node_a!r} twice")
        name = f"edge {self.node_a}-{self.node_b}"
        pose = check_finite(check_shape(as_float_array(self.pose, f"{name} pose"), (3,),
                                        f"{name} pose"), f"{name} pose")
        cov = check_finite(check_shape(as_float_array(self.covariance, f"{name} covariance"),
                                       (3, 3), f"{name} covariance"), f"{name} covariance")
        cov = 0.5 * (cov + cov.T)
        try:
            np.linalg.cholesky(cov)
        except np.linalg.LinAlgError:
            raise ValidationError(f"{name} covariance must be positive definite, got "
                                  f"eigenvalues {np.linalg.eigvalsh(cov)}") from None
        object.__setattr__(self, "pose", pose)
        object.__setattr__(self, "covariance", cov)

    @classmethod
    def from_pairwise(cls, node_a: str, node_b: str, cal: PairwiseCalibration) -> "PoseEdge":
        return cls(node_a=node_a, node_b=node_b, pose=cal.pose, covariance=cal.covariance,
                   rmse_m=cal.rmse_m, n_frames=cal.n_frames, lag_frames=cal.lag_frames)


@dataclass(frozen=True, kw_only=True, slots=True)
class PoseGraphCalibration:
    """Every reachable node's pose in the reference frame.

    poses : name -> (3,) ``(x_m, y_m, phi_rad)``; covariances : name -> (3, 3)
    marginal covariance (body tangent); lag_frames : name -> frame lag relative
    to the reference (the node's frame ``k + lag`` is the reference's frame
    ``k``), summed along the breadth-first path; unreachable : nodes without a
    path to the reference; edges : the edges used; final_error : the graph's
    error (0.5 * sum of squared whitened residuals) at the solution.
    """

    reference: str
    poses: Mapping[str, NDArray]
    covariances: Mapping[str, NDArray]
    lag_frames: Mapping[str, int]
    unreachable: tuple[str, ...]
    edges: tuple[PoseEdge, ...]
    success: bool
    message: str
    iterations: int = 0
    final_error: float = float("nan")
    failures: Mapping[str, str] = field(default_factory=dict)


def _bfs(reference: str, names: Sequence[str], edges: Sequence[PoseEdge]):
    """Initial poses and lags by composing edges outward from the reference."""
    adj: dict[str, list[tuple[str, gtsam.Pose2, int]]] = {n: [] for n in names}
    for e in edges:
        t = to_pose2(e.pose)
        adj[e.node_a].append((e.node_b, t, e.lag_frames))
        adj[e.node_b].append((e.node_a, t.inverse(), -e.lag_frames))
    init = {reference: gtsam.Pose2()}
    lags = {reference: 0}
    queue = deque([reference])
    while queue:
        a = queue.popleft()
        for b, t_ab, lag in adj[a]:
            if b not in init:
                init[b] = init[a].compose(t_ab)
                lags[b] = lags[a] + lag
                queue.append(b)
    return init, lags


def pose_graph_calibration(
    node_names: Sequence[str],
    edges: Sequence[PoseEdge],
    *,
    reference: str | None = None,
    max_iterations: int = 100,
    failures: Mapping[str, str] | None = None,
) -> PoseGraphCalibration:
    """Solve the pose graph of pairwise estimates (module doc).

    node_names : every node of the network, in order; the first is the
        reference unless ``reference`` names another.
    edges : pairwise relative poses between those nodes.
    failures : pair -> reason, from :func:`pairwise_edges`, kept in the result.
    Returns a :class:`PoseGraphCalibration`; ``success`` is False when a node
    is unreachable (the others are still solved) or LM or the marginals fail.
    """
    names = [str(n) for n in node_names]
    if not names or len(set(names)) != len(names):
        raise ValidationError(f"node_names must be unique and non-empty, got {names!r}")
    ref = names[0] if reference is None else str(reference)
    if ref not in names:
        raise ValidationError(f"reference={ref!r} is not one of the nodes {names!r}")
    for e in edges:
        for n in (e.node_a, e.node_b):
            if n not in names:
                raise ValidationError(f"edge {e.node_a}-{e.node_b} names node {n!r}, which is "
                                      f"not one of {names!r}")
    init, lags = _bfs(ref, names, edges)
    reachable = [n for n in names if n in init]
    unreachable = tuple(n for n in names if n not in init)
    key = {n: i for i, n in enumerate(reachable)}
    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.PriorFactorPose2(key[ref], gtsam.Pose2(),
                                     gtsam.noiseModel.Isotropic.Sigma(3, ANCHOR_SIGMA)))
    used = []
    for e in edges:
        if e.node_a in key and e.node_b in key:
            graph.add(gtsam.BetweenFactorPose2(key[e.node_a], key[e.node_b], to_pose2(e.pose),
                                               gtsam.noiseModel.Gaussian.Covariance(e.covariance)))
            used.append(e)
    values = gtsam.Values()
    for n in reachable:
        values.insert(key[n], init[n])
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(int(max_iterations))
    opt = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
    try:
        result = opt.optimize()
        marg = gtsam.Marginals(graph, result)
        covs = {}
        for n in reachable:
            covs[n] = (np.zeros((3, 3)) if n == ref
                       else 0.5 * (marg.marginalCovariance(key[n]) + marg.marginalCovariance(key[n]).T))
    except RuntimeError as exc:  # indeterminant system: cannot happen with PD edges
        return PoseGraphCalibration(
            reference=ref, poses={}, covariances={}, lag_frames={}, unreachable=unreachable,
            edges=tuple(used), success=False, message=f"pose graph solve failed: {exc}",
            failures=dict(failures or {}))
    poses = {n: (np.zeros(3) if n == ref else pose_array(result.atPose2(key[n])))
             for n in reachable}
    msg = f"{len(reachable)} node(s) calibrated from {len(used)} edge(s)"
    if unreachable:
        msg += f"; no path to {ref}: {', '.join(unreachable)}"
    return PoseGraphCalibration(
        reference=ref, poses=poses, covariances=covs, lag_frames={n: lags[n] for n in reachable},
        unreachable=unreachable, edges=tuple(used), success=not unreachable, message=msg,
        iterations=int(opt.iterations()), final_error=float(graph.error(result)),
        failures=dict(failures or {}))


def pairwise_edges(
    tracks: Mapping[str, LocalTracks],
    *,
    pairs: Sequence[tuple[str, str]] | None = None,
    **match_kwargs,
) -> tuple[list[PoseEdge], dict[str, str]]:
    """Match every pair of nodes (or the given ``pairs``) and turn each
    successful match into a :class:`PoseEdge`.

    tracks : node name -> its local tracks, in network order.
    match_kwargs : passed to :func:`match_tracks`.
    Returns the edges and, for each failed pair ``"a-b"``, the reason.
    """
    names = list(tracks)
    if pairs is None:
        pairs = [(names[i], names[j]) for i in range(len(names)) for j in range(i + 1, len(names))]
    edges, failures = [], {}
    for a, b in pairs:
        m = match_tracks(tracks[a], tracks[b], **match_kwargs)
        if m.success:
            edges.append(PoseEdge.from_pairwise(a, b, m.calibration))
        else:
            failures[f"{a}-{b}"] = m.message
    return edges, failures
