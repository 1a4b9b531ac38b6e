"""A pose covariance of the joint calibration graph that holds when the
errors are correlated in time and the model is not exact.

The graph's marginal covariance (its inverse Hessian) treats every frame as
an independent draw from the measurement model. On recorded TI data neither
holds: a person's centroid wanders over the body as the aspect changes,
clusters split and merge, the association errs for stretches of frames.
Such errors last seconds, and the poses' scores carry them: the two halves
of a shared recording calibrated apart disagreed by 6-10 of their reported
sigmas (docs/CALIBRATION.md, "Covariance on real data").

The estimate is a sum over frames: at the solution, with the target states
eliminated, the pose block moves by ``sum_k x_k`` when the data change, with
frame ``k``'s *influence* ``x_k = S^-1 psi_k`` (``S`` the Schur complement
of the Gauss-Newton system onto the pose block, ``psi_k`` frame ``k``'s
score with the states eliminated:
:func:`~mmsnap_graph.calibration.joint.presolve.pose_influences`). The
influences sum to zero at the optimum; when the model holds, their summed
outer products have the expectation ``S^-1``, the marginal. Their *long-run*
covariance, Bartlett (Newey-West) weights over ``bandwidth`` frames
(:func:`long_run_covariance`), holds under any correlation shorter than the
bandwidth. :func:`robust_covariance` keeps the model's marginal unless the
long-run estimate exceeds it, over the whole block, by more than its own
sampling noise; then it reports the long-run estimate (never below the
model in any direction) times the small-sample factor of a covariance
estimated with ``nu = 3 T / (2 L)`` degrees of freedom, ``nu / (nu - P -
1)``. A rule per direction (widen where the long-run estimate exceeds the
model by two standard errors) is too eager: each recording's covariance is
estimated from its own frames, and the inverse of a noisy covariance is too
large on the average (docs/CALIBRATION.md, "Covariance on real data
(long-run)"; docs/validation/calibration.md, "Figures behind the estimators' rules").

A bias that every frame shares is not in any of this: the influences of
frames that all agree on a wrong pose sum to zero as well. A person's
reflection depth ``d`` (each radar's centroid nearer to it than the body's
centre) is such a bias, and where the geometry cannot separate it from the
poses (two radars at right angles with the walker in a small area: it
moves S2 along the baseline like a shorter baseline would) the poses take it
in. :func:`range_offset_response` is the poses' response ``J`` to every
range lengthened alike, ``J_n`` to node ``n``'s ranges alone (``J = sum_n
J_n``). Each radar sees its own side of the body, so the depths are not one
number: node ``n``'s is ``d + e_n``, a common part and the node's own, of
mean squares ``(1 - q) s^2`` and ``q s^2`` (``q`` =
:data:`NODE_DEPTH_SHARE`, the physical prior 0.10 +- 0.05 m: ``s^2`` its
mean square, ``q s^2`` its variance). ``block_covariance(...,
range_offset_rms=s)`` adds ``s^2 ((1 - q) J J^T + q sum_n J_n J_n^T)`` to
the reported covariance (*considered* parameters, the Schmidt "consider"
covariance: the poses are not moved). On the simulator's real model it
brings the pose NEES into its band (docs/validation/calibration.md, "The
calibrated pose on the simulator's real model").

Whether the geometry separates the depth from the poses is measured, not
assumed: :func:`depth_data_sigma` is the depth's sigma from the data alone
(the common range offset added to the graph at the solution with a flat
prior, its long-run variance with the poses and states free), reported
beside the considered term (``PoseCovariance.depth_data_sigma_m``). It is
not used to switch to estimating the depth: where the data fix it to less
than half the considered rms the estimate still takes up other model errors.
Two radars 8 m apart facing each other, one walker (the simulator's real
model, 600 frames): 0.19 m, and the offset estimated with a flat prior is
-0.76 +- 0.17 m for a simulated depth of about 0.05 m; three radars around
the walker: 0.04 m. On the shared fall-detection recording (0.047 m)
estimating it moved S2 from 0.059 m to 0.150 m off the tape with a reported
position sigma of 0.02-0.04 m (docs/validation/calibration.md, "Facing
radars").
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ...data.calibration_facts import PoseCovariance
from ...errors import ValidationError
from .presolve import RANGE_OFFSET, PresolveProblem, pose_influences

__all__ = ["BlockCovariance", "block_covariance", "long_run_covariance", "robust_covariance",
           "range_offset_response", "depth_data_sigma", "bandwidth_frames", "NODE_DEPTH_SHARE",
           "DEFAULT_BANDWIDTH_S", "MAX_GAP_FRAMES"]

#: Default Bartlett bandwidth (s): a walker's aspect and a cluster's shape
#: change within about this; the real recordings' influences stay correlated
#: up to 2 s (docs/CALIBRATION.md).
DEFAULT_BANDWIDTH_S = 2.0
#: Gaps between frames longer than this are shortened to it (the series is
#: uncorrelated across them anyway).
MAX_GAP_FRAMES = 64
#: The share of the considered reflection depth's mean square that is each
#: node's own (module doc): the prior 0.10 +- 0.05 m, 0.05^2 / (0.10^2 +
#: 0.05^2).
NODE_DEPTH_SHARE = 0.2


def bandwidth_frames(bandwidth_s: float, frame_period_s: float | None) -> int:
    """The bandwidth in whole frames (at least 1); 1 without a frame period."""
    if frame_period_s is None:
        return 1
    return max(int(np.ceil(float(bandwidth_s) / float(frame_period_s) - 1e-9)), 1)


def _dense(x: NDArray, frames: NDArray) -> NDArray:
    """The rows on a zero-filled time axis (gaps shortened)."""
    gaps = np.minimum(np.diff(frames), MAX_GAP_FRAMES)
    if gaps.size and gaps.min() < 1:
        raise ValidationError("frames must be strictly increasing")
    slot = np.concatenate([[0], np.cumsum(gaps)]).astype(np.int64)
    out = np.zeros((int(slot[-1]) + 1, x.shape[1]))
    out[slot] = x
    return out


def long_run_covariance(influences: ArrayLike, frames: ArrayLike, bandwidth: int) -> NDArray:
    """Bartlett (Newey-West) long-run covariance ``sum_l w_l sum_t x_t
    x_{t+l}^T`` (``w_l = 1 - l / (L + 1)``, both signs of ``l``) of the
    influence series ``(F, P)`` on ``frames`` (F,) strictly increasing ints
    (module doc)."""
    x = np.asarray(influences, dtype=float)
    t = np.asarray(frames, dtype=np.int64).ravel()
    if x.ndim != 2 or x.shape[0] != t.size:
        raise ValidationError(f"influences {x.shape} and frames {t.shape} do not match")
    if isinstance(bandwidth, bool) or int(bandwidth) < 0:
        raise ValidationError(f"bandwidth must be an integer >= 0, got {bandwidth!r}")
    dense = _dense(x, t) if t.size else x
    om = dense.T @ dense
    bw = int(bandwidth)
    for lag in range(1, min(bw, dense.shape[0] - 1) + 1):
        gl = dense[lag:].T @ dense[:-lag]
        om += (1.0 - lag / (bw + 1.0)) * (gl + gl.T)
    return 0.5 * (om + om.T)


def robust_covariance(model: ArrayLike, long_run: ArrayLike, *, n_frames: int,
                      bandwidth: int) -> tuple[NDArray, NDArray]:
    """The model's covariance, or the long-run covariance where the errors
    are correlated beyond sampling noise (module doc), and the factors (P,)
    on the variances in the model's whitened directions (1 where kept).

    In the model-whitened frame the long-run covariance has eigenvalues
    ``lambda_i``, each a Bartlett estimate with about ``nu = 3 T / (2 L)``
    degrees of freedom (``L`` the bandwidth, ``T`` the frames; relative
    standard error ``sqrt(4 L / (3 T))``). When their mean exceeds 1 by
    more than two standard errors of a mean of ``P`` of them, the reported
    variances are ``max(c lambda_i, 1)`` with ``c = nu / (nu - P - 1)``:
    the inverse of a covariance estimated with ``nu`` degrees of freedom is
    too large on the average by ``nu / (nu - P - 1)`` (inverse Wishart), so
    an unbiased long-run estimate alone still gives a NEES above ``P``.
    Otherwise the model's marginal is kept whole: there the long-run
    estimate is its own noise, and taking the larger of the two in some
    directions made the covariance too large on the average."""
    m = np.asarray(model, dtype=float)
    lr = np.asarray(long_run, dtype=float)
    w, v = np.linalg.eigh(0.5 * (m + m.T))
    p = m.shape[0]
    if not np.all(np.isfinite(w)) or w.min() <= 0:
        return m, np.ones(p)
    root = v * np.sqrt(w)
    inv_root = v / np.sqrt(w)
    white = inv_root.T @ lr @ inv_root
    lw, lv = np.linalg.eigh(0.5 * (white + white.T))
    rel_se = np.sqrt(4.0 * max(int(bandwidth), 1) / (3.0 * max(int(n_frames), 1)))
    if not lw.mean() > 1.0 + 2.0 * rel_se / np.sqrt(p):
        return m, np.ones(p)
    nu = 2.0 / rel_se**2
    lam = np.maximum(lw * nu / max(nu - p - 1.0, 1.0), 1.0)
    out = root @ (lv * lam) @ lv.T @ root.T
    return 0.5 * (out + out.T), np.sort(lam)[::-1]


@dataclass(frozen=True, slots=True)
class BlockCovariance:
    """The covariance of the joint graph's pose block at its solution.

    covariance, model : (P, P) the reported and the model's (the marginal
        of the graph: ``S^-1``), in the block's order (:attr:`order`).
    order : ``("pose", name)`` x 3 per non-reference node, ``("offset",
        name)`` per timed node, ``("range",)`` for the range offset.
    factors : (P,) the widening of the variances in the model's whitened
        directions (1 where the model's was kept).
    bandwidth : Bartlett bandwidth in frames (0 for the model's).
    range_offset_rms : the considered reflection depth (m) whose ``s^2 J
        J^T`` is in :attr:`covariance` (0: none).
    random : (P, P) :attr:`covariance` without the considered depth's term
        (the part that averages down over independent stretches of data;
        None: the same as :attr:`covariance`).
    depth_response : (P, C) the considered depth's columns ``M``, so that
        the term is ``s^2 M M^T``: ``sqrt(1 - q) J`` for the depth every
        node shares, then ``sqrt(q) J_n`` for each node's own (``q`` =
        :data:`NODE_DEPTH_SHARE`); the same depths in every window of a
        recording, so a windowed solve combines the columns, not their
        outer products (:mod:`.windowed`). ``depth_columns`` names them:
        ``("common",)`` then ``("node", name)``. Empty without the term.
    """

    covariance: NDArray
    model: NDArray
    order: tuple
    factors: NDArray
    bandwidth: int
    range_offset_rms: float = 0.0
    random: NDArray | None = None
    depth_response: NDArray | None = None
    depth_columns: tuple = ()
    depth_data_sigma_m: float = 0.0

    def node(self, name: str) -> NDArray:
        """(3, 3) the covariance of ``name``'s pose."""
        i = self.order.index(("pose", name))
        return self.covariance[i:i + 3, i:i + 3].copy()

    def variance(self, key: tuple) -> float:
        """The variance of a clock offset ``("offset", name)`` or of the
        range offset ``("range",)``; NaN when not in the block."""
        if key not in self.order:
            return float("nan")
        i = self.order.index(key)
        return float(self.covariance[i, i])

    def fact(self) -> PoseCovariance:
        """How the covariance was computed, as the calibration reports it
        (with the considered depth: each node's sigmas without its term)."""
        if self.bandwidth == 0:
            return PoseCovariance(method="marginals")
        names, sigmas = [], []
        if self.range_offset_rms > 0 and self.random is not None:
            for key in dict.fromkeys(k for k in self.order if k[0] == "pose"):
                i = self.order.index(key)
                block = self.random[i:i + 3, i:i + 3]
                names.append(key[1])
                sigmas.extend(np.sqrt(np.clip(np.diag(block), 0.0, None)).tolist())
        return PoseCovariance(method="long_run", bandwidth_frames=self.bandwidth,
                              max_widening=max(float(np.max(self.factors)), 1.0),
                              reflection_depth_rms_m=self.range_offset_rms,
                              depth_data_sigma_m=self.depth_data_sigma_m,
                              without_depth_nodes=tuple(names),
                              without_depth_sigmas=tuple(sigmas))


def range_offset_response(problem: PresolveProblem, poses, states, offsets,
                          influences: NDArray | None = None, *,
                          node: str | None = None) -> NDArray:
    """(P,) the pose block's response (per metre) to every range of
    ``problem`` lengthened alike (``node`` given: that node's ranges only),
    at its solution ``(poses, states, offsets)``: the Gauss-Newton step after
    the shift, ``-S^-1 sum_k
    psi_k`` (the influences ``S^-1 psi_k`` are gradients of the cost, they
    sum to zero at the solution, and they are linear in the measurements, so
    the step is exact for the linearised graph)."""
    if influences is None:
        influences, _ = pose_influences(problem, poses, states, offsets=offsets)
    step = 0.01
    if node is not None and node not in problem.measurements:
        raise ValidationError(f"node={node!r} is not in the problem's nodes "
                              f"{sorted(problem.measurements)}")
    shifted = {n: np.asarray(m, dtype=float) + (np.array([step, 0.0, 0.0])
                                                if node in (None, n) else 0.0)
               for n, m in problem.measurements.items()}
    moved, _ = pose_influences(dataclasses.replace(problem, measurements=shifted), poses, states,
                               offsets=offsets)
    return -(moved.sum(axis=0) - np.asarray(influences).sum(axis=0)) / step


def depth_data_sigma(problem: PresolveProblem, poses, states, offsets, frames, *,
                     bandwidth: int | None) -> float:
    """The reflection depth's sigma (m) from the data alone at the solution
    ``(poses, states, offsets)`` of ``problem`` (which does not estimate
    it): a range offset common to every node added with a flat prior, its
    variance with the poses, clock offsets and states free; the long-run
    (robust) variance with ``bandwidth`` frames, the model's with None; 0
    when it cannot be computed (a variance not finite and positive)."""
    if problem.range_offset is not None:
        raise ValidationError("depth_data_sigma: the problem already estimates the range offset")
    flat = dataclasses.replace(problem, range_offset=(0.0, 1e3))
    given = {**(dict(offsets) if offsets else {}), RANGE_OFFSET: 0.0}
    infl, model = pose_influences(flat, poses, states, offsets=given)
    cov = model
    if bandwidth is not None:
        cov, _ = robust_covariance(model, long_run_covariance(infl, frames, bandwidth),
                                   n_frames=len(frames), bandwidth=bandwidth)
    var = float(cov[-1, -1])
    return float(np.sqrt(var)) if np.isfinite(var) and var > 0 else 0.0


def block_covariance(problem: PresolveProblem, poses, states, offsets, frames, *,
                     bandwidth: int | None, timed,
                     range_offset_rms: float | None = None) -> BlockCovariance:
    """:class:`BlockCovariance` of ``problem`` (Gaussian, the final pass's
    detections and motion factors) at ``(poses, states, offsets)``;
    ``bandwidth`` None: the model's (the graph's marginals alone); ``timed``
    the nodes with clock offsets; ``range_offset_rms`` (m): a reflection
    depth not estimated, considered in the long-run covariance (module doc;
    ignored when ``problem`` estimates the range offset; the nodes' own parts
    included)."""
    infl, model = pose_influences(problem, poses, states, offsets=offsets)
    others = [n for n in problem.names if n != problem.reference]
    order = tuple([("pose", n) for n in others for _ in range(3)]
                  + [("offset", n) for n in others if n in set(timed)]
                  + ([("range",)] if problem.range_offset is not None else []))
    # One key per column; a pose's three columns share a key: index() finds the first.
    if bandwidth is None:
        return BlockCovariance(model, model, order, np.ones(model.shape[0]), 0)
    lr = long_run_covariance(infl, frames, bandwidth)
    cov, factors = robust_covariance(model, lr, n_frames=len(frames), bandwidth=bandwidth)
    bw, rms, random = int(bandwidth), 0.0, cov
    if range_offset_rms is not None and range_offset_rms > 0 and problem.range_offset is None:
        rms = float(range_offset_rms)
        q = NODE_DEPTH_SHARE
        cols = [np.sqrt(1.0 - q) * range_offset_response(problem, poses, states, offsets, infl)]
        cols += [np.sqrt(q) * range_offset_response(problem, poses, states, offsets, infl, node=n)
                 for n in problem.names]
        m = np.column_stack(cols)
        cov = cov + rms**2 * (m @ m.T)
        alone = depth_data_sigma(problem, poses, states, offsets, frames, bandwidth=bw)
        return BlockCovariance(cov, model, order, factors, bw, rms, random, m,
                               (("common",), *(("node", n) for n in problem.names)), alone)
    return BlockCovariance(cov, model, order, factors, bw, rms, random)
