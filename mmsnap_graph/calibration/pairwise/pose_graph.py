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

Edges from matched tracks (:func:`pairwise_edges`) carry their matched
points. Pairwise estimates that reuse one node's detections are correlated,
and the between-factor graph, which takes them as independent, reports
covariances that are too small (docs/CALIBRATION.md, "Network: all poses
from the matched points"). When every edge has its points, ``method="auto"``
(default) solves all poses at once from the points instead
(:mod:`.point_graph`: one least squares, a sandwich covariance with the
residuals of one instant counted together and corrected for frame-to-frame
correlation); the between-factor graph then only gives the starting poses.
"""

from __future__ import annotations

import dataclasses
from collections import deque
from typing import Literal, Mapping, Sequence

import gtsam
import numpy as np

from ...data.calibration import PairwiseCalibration, RecordingCalibration
from ...data.calibration_facts import CalibrationStatus, PoseGraphFit, SolveBrokeDown
from ...errors import ValidationError
from .centroid_points import debias_centroid_tracks
from .matching import LocalTracks, match_tracks
from .matching_options import MatchingOptions
from .point_graph import PointEdge, solve_point_graph
from ..poses import pose_array, to_pose2

__all__ = ["pose_graph_calibration", "pairwise_edges"]

#: Sigma of the prior that anchors the reference node (m and rad): small
#: enough to be a constraint, large enough to keep the Cholesky well scaled.
ANCHOR_SIGMA = 1e-6
#: Smallest edge sigma the graph uses (m and rad; added in quadrature): a
#: noise-free pair fits exactly and its closed-form covariance is rounding's
#: (sigma ~1e-14), which GTSAM cannot factor next to the anchor ("indeterminate
#: linear system": no poses at all where the exact poses are the answer). A
#: micrometre is far below any radar's resolution.
EDGE_SIGMA_FLOOR = 1e-6
#: The between-factor graph gives the joint covariance of all non-reference
#: poses up to this many of them (beyond, the marginals only: the joint
#: marginal of a large graph costs more than the solve).
MAX_JOINT_NODES = 16


def _bfs(reference: str, names: Sequence[str], edges: Sequence[PairwiseCalibration]):
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


def _validate_graph(node_names, edges, reference, method) -> tuple[list[str], str]:
    names = [str(n) for n in node_names]
    if not names or len(set(names)) != len(names):
        raise ValidationError(f"node_names must be unique and non-empty, got {names!r}")
    ref = names[0] if reference is None else str(reference)
    if ref not in names:
        raise ValidationError(f"reference={ref!r} is not one of the nodes {names!r}")
    if method not in ("auto", "points", "edges"):
        raise ValidationError(f"method={method!r} must be 'auto', 'points' or 'edges'")
    for e in edges:
        for n in (e.node_a, e.node_b):
            if n not in names:
                raise ValidationError(f"edge {e.node_a}-{e.node_b} names node {n!r}, which is "
                                      f"not one of {names!r}")
    if method == "points" and not all(e.has_points for e in edges):
        raise ValidationError("method='points' needs every edge's matched points "
                              "(PairwiseCalibration.points_a_m, points_b_m)")
    return names, ref


def _solve_edges(ref, reachable, init, used, max_iterations):
    """The between-factor graph: poses, marginals, joint covariance (None
    beyond :data:`MAX_JOINT_NODES`), LM iterations and error. Raises
    RuntimeError when GTSAM cannot solve."""
    key = {n: i for i, n in enumerate(reachable)}
    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.PriorFactorPose2(key[ref], gtsam.Pose2(),
                                     gtsam.noiseModel.Isotropic.Sigma(3, ANCHOR_SIGMA)))
    for e in used:
        graph.add(gtsam.BetweenFactorPose2(key[e.node_a], key[e.node_b], to_pose2(e.pose),
                                           gtsam.noiseModel.Gaussian.Covariance(
                                               e.covariance + EDGE_SIGMA_FLOOR ** 2 * np.eye(3))))
    values = gtsam.Values()
    for n in reachable:
        values.insert(key[n], init[n])
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(int(max_iterations))
    opt = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
    result = opt.optimize()
    marg = gtsam.Marginals(graph, result)
    others = [n for n in reachable if n != ref]
    covs = {n: marg.marginalCovariance(key[n]) for n in others}
    joint = None
    if 0 < len(others) <= MAX_JOINT_NODES:
        kv = gtsam.KeyVector()
        for n in others:
            kv.append(key[n])
        joint = marg.jointMarginalCovariance(kv).fullMatrix()
        joint = 0.5 * (joint + joint.T)
    poses = {n: (np.zeros(3) if n == ref else pose_array(result.atPose2(key[n])))
             for n in reachable}
    return poses, covs, joint, int(opt.iterations()), float(graph.error(result))


def _point_edges(used, lags) -> list[PointEdge]:
    """The edges' matched points with each row's time on the reference clock
    (a's frame minus a's lag; rows without frames get times of their own)."""
    out = []
    for j, e in enumerate(used):
        k = e.points_a_m.shape[0]
        if e.frames is not None:
            times = e.frames - int(lags[e.node_a])
        else:  # unknown times: never clustered with another edge's rows
            times = np.arange(k) - (j + 1) * (1 << 40)
        out.append(PointEdge(node_a=e.node_a, node_b=e.node_b, points_a_m=e.points_a_m,
                             points_b_m=e.points_b_m, times=times))
    return out


def pose_graph_calibration(
    node_names: Sequence[str],
    edges: Sequence[PairwiseCalibration],
    *,
    reference: str | None = None,
    max_iterations: int = 100,
    failures: Mapping[str, str] | None = None,
    method: Literal["auto", "points", "edges"] = "auto",
    autocorrelation: Literal["auto", "none"] = "auto",
) -> RecordingCalibration:
    """Solve the pose graph of pairwise estimates (module doc).

    node_names : every node of the network, in order; the first is the
        reference unless ``reference`` names another.
    edges : pairwise relative poses between those nodes (each a successful
        :class:`~mmsnap_graph.data.calibration.PairwiseCalibration`).
    failures : pair -> reason, from :func:`pairwise_edges`, kept in the result.
    method : ``"points"`` solves every pose at once from the edges' matched
        points (:mod:`.point_graph`; ValidationError if an edge has none),
        ``"edges"`` the between-factor graph of the pairwise estimates,
        ``"auto"`` the points when every edge has them.
    autocorrelation : ``"auto"`` corrects the points solve's covariance for
        frame-to-frame correlated residuals, ``"none"`` does not.
    Returns a :class:`~mmsnap_graph.data.calibration.RecordingCalibration`
    with ``method="pose_graph"``, ``lag_frames`` summed along the
    breadth-first path from the reference, the joint covariance of the
    non-reference poses (the between-factor graph's only up to
    :data:`MAX_JOINT_NODES` of them) and a
    :class:`~mmsnap_graph.data.calibration_facts.PoseGraphFit` fact (which
    solve, iterations, final error); ``status`` is ``NODES_UNREACHABLE`` when
    a node has no path to the reference (the others are still solved),
    ``SOLVE_FAILED`` when a solve fails.
    """
    names, ref = _validate_graph(node_names, edges, reference, method)
    if autocorrelation not in ("auto", "none"):
        raise ValidationError(f"autocorrelation={autocorrelation!r} must be 'auto' or 'none'")
    init, lags = _bfs(ref, names, edges)
    reachable = [n for n in names if n in init]
    unreachable = tuple(n for n in names if n not in init)
    used = [e for e in edges if e.node_a in init and e.node_b in init]
    use_points = method == "points" or (method == "auto" and bool(used)
                                         and all(e.has_points for e in used))
    others = tuple(n for n in reachable if n != ref)
    solve = "points" if use_points else "edges"
    tau = 1.0
    common = dict(reference=ref, node_names=tuple(names), unreachable=unreachable,
                  edges=tuple(used), method="pose_graph", failures=dict(failures or {}))
    try:
        poses, covs, joint, iterations, final_error = _solve_edges(ref, reachable, init, used,
                                                                   max_iterations)
        if use_points and others:
            sol = solve_point_graph(ref, poses, _point_edges(used, lags),
                                    autocorrelation=autocorrelation == "auto")
            poses = {n: sol.poses[n] for n in reachable}
            joint, tau, iterations = sol.covariance, sol.autocorrelation_factor, sol.iterations
            final_error = 0.5 * sol.cost_m2
            covs = {n: joint[3 * i:3 * i + 3, 3 * i:3 * i + 3].copy()
                    for i, n in enumerate(others)}
    except (RuntimeError, np.linalg.LinAlgError) as exc:  # cannot happen with PD edges
        return RecordingCalibration(
            **common, poses={}, covariances={}, lag_frames={},
            status=CalibrationStatus.SOLVE_FAILED,
            facts=(SolveBrokeDown(step="pose_graph", reason=str(exc).strip() or
                                  type(exc).__name__),))
    covs = {ref: np.zeros((3, 3)), **{n: 0.5 * (c + c.T) for n, c in covs.items()}}
    fit = PoseGraphFit(solve=solve, n_nodes=len(reachable), n_edges=len(used),
                       iterations=iterations, final_error=final_error,
                       autocorrelation_factor=tau)
    return RecordingCalibration(
        **common, poses=poses, covariances={n: covs[n] for n in reachable},
        lag_frames={n: lags[n] for n in reachable},
        status=(CalibrationStatus.NODES_UNREACHABLE if unreachable else CalibrationStatus.OK),
        facts=(fit,), joint_covariance=joint, joint_order=others if joint is not None else (),
        model_covariances={n: covs[n] for n in reachable})


def pairwise_edges(
    tracks: Mapping[str, LocalTracks],
    *,
    frame_period_s: float,
    options: MatchingOptions | None = None,
    pairs: Sequence[tuple[str, str]] | None = None,
    debias_centroids: bool = True,
) -> tuple[list[PairwiseCalibration], dict[str, str]]:
    """Match every pair of nodes (or the given ``pairs``) and turn each
    successful match into an edge (the match's
    :class:`~mmsnap_graph.data.calibration.PairwiseCalibration` with the
    nodes' names and the lag's evidence).

    tracks : node name -> its local tracks, in network order.
    debias_centroids : centroid tracks (``source="centroids"``, no
        covariances) first lose the boresight bias of their angle noise
        (:func:`~mmsnap_graph.calibration.pairwise.centroid_points.debias_centroid_tracks`:
        a bias common to every frame, which the pose covariance cannot show).
    frame_period_s, options : the frame period and the thresholds of
        :func:`match_tracks`.
    Returns the edges and, for each failed pair ``"a-b"``, the reason.
    """
    if debias_centroids:
        tracks = {n: debias_centroid_tracks(t)[0] for n, t in tracks.items()}
    names = list(tracks)
    if pairs is None:
        pairs = [(names[i], names[j]) for i in range(len(names)) for j in range(i + 1, len(names))]
    edges, failures = [], {}
    for a, b in pairs:
        m = match_tracks(tracks[a], tracks[b], frame_period_s=frame_period_s, options=options)
        if m.success:
            evidence = (None if m.lag_evidence is None else
                        dataclasses.replace(m.lag_evidence, node_a=a, node_b=b))
            edges.append(dataclasses.replace(m.calibration, node_a=a, node_b=b,
                                             lag_evidence=evidence,
                                             lag_ambiguous=m.lag_ambiguous))
        else:
            failures[f"{a}-{b}"] = m.message
    return edges, failures
