"""The joint calibration graph in GTSAM (:mod:`.solve`): keys, factors and
values; the outlier test; the marginal covariances and unobservable
directions of a solution.

Unknowns: every non-reference node's ``Pose2`` (keys ``x``), each frame's
target state (keys ``v``) and, when clock offsets are estimated, each
non-reference node's residual clock offset in seconds on top of its whole
frame lag (keys ``t``, ``Vector1``; the node measures ``F(tau) x_k``,
:func:`factors.gtsam_factors.timed_pose_measurement_factor`).
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np
from numpy.typing import NDArray

from factors.gtsam_factors import (
    constant_velocity_factor,
    node_measurement_factor,
    pose_measurement_factor,
    state_prior_factor,
    timed_pose_measurement_factor,
)
from factors.models import measurement_model, residual

from ..._validation import chi2_gate
from ..poses import pose_array, to_pose2
from .presolve import motion_norms, shifted_states

__all__ = ["MotionSpec", "motion_spec", "JointGraph", "flag_outliers", "flag_turns",
           "exonerate_turns", "TURN_POSITION_SIGMA_M",
           "assess", "schur_covariances"]


@dataclass(frozen=True, slots=True)
class MotionSpec:
    """The constant-velocity factors: between states ``index`` and ``index +
    1``, ``dt_s`` apart, white acceleration ``sigma_a_mps2``, optionally under
    a kernel ``robust`` of width ``k`` (on the whitened 4-vector norm)."""

    index: NDArray
    dt_s: NDArray
    sigma_a_mps2: float
    robust: str | None = None
    k: float = 1.0

    def as_tuple(self):
        """The pre-solve's ``motion`` tuple (:mod:`.presolve`)."""
        return (self.index, self.dt_s, self.sigma_a_mps2, self.robust, self.k)

    def subset(self, keep: NDArray, robust: str | None) -> "MotionSpec":
        return MotionSpec(self.index[keep], self.dt_s[keep], self.sigma_a_mps2, robust, self.k)


def motion_spec(frames, motion, frame_period_s, max_motion_gap_frames, sigma_a_mps2,
                robust=None, k=1.0) -> MotionSpec | None:
    """The constant-velocity factors between frames no more than
    ``max_motion_gap_frames`` apart, or None without motion."""
    if not motion:
        return None
    gaps = np.diff(frames)
    mi = np.flatnonzero(gaps <= max_motion_gap_frames)
    return MotionSpec(mi, gaps[mi] * float(frame_period_s), float(sigma_a_mps2), robust, float(k))


class JointGraph:
    """The joint calibration graph in GTSAM: keys, factors and values."""

    def __init__(self, meas_f, active, ref, prior_sig, motion: MotionSpec | None, timed=()):
        self.meas, self.active, self.ref = meas_f, active, ref
        self.prior_sig, self.motion = prior_sig, motion
        self.timed = [n for n in active if n != ref and n in set(timed)]
        self.f = next(iter(meas_f.values())).shape[0]
        self.pose_key = {n: gtsam.symbol("x", i) for i, n in enumerate(active)}
        self.offset_key = {n: gtsam.symbol("t", i) for i, n in enumerate(active)
                           if n in self.timed}
        self.state_key = [gtsam.symbol("v", k) for k in range(self.f)]
        #: name -> -lag * frame period (s): the offset the frames already remove.
        self.lag_offsets = {n: 0.0 for n in active}
        #: The range offset (m) added to every measured range so far (the
        #: estimated reflection depth: the graph's factors then see ranges
        #: of the body's centre).
        self.range_offset_m = 0.0
        #: (steps, converged) of each numpy pre-solve run.
        self.presolve_steps: list[tuple[int, bool]] = []
        self.frame_period_s: float | None = None

    def shift_ranges(self, offset_m: float) -> None:
        """Add ``offset_m`` to every measured range (an estimated range
        offset, :attr:`range_offset_m` keeps the total)."""
        if offset_m:
            self.meas = {n: z + np.array([offset_m, 0.0, 0.0]) for n, z in self.meas.items()}
            self.range_offset_m += float(offset_m)

    def _measurement(self, n, k, z, noise):
        if n == self.ref:
            return node_measurement_factor(self.state_key[k], np.zeros(3), z, noise)
        if n in self.offset_key:
            return timed_pose_measurement_factor(self.pose_key[n], self.state_key[k],
                                                 self.offset_key[n], z, noise)
        return pose_measurement_factor(self.pose_key[n], self.state_key[k], z, noise)

    def build(self, noise, use, motion: MotionSpec | None = None) -> gtsam.NonlinearFactorGraph:
        """The graph on the detections ``use`` (name -> (F,) bool), with the
        motion factors of ``motion`` (default: the graph's)."""
        motion = self.motion if motion is None else motion
        g = gtsam.NonlinearFactorGraph()
        for n in self.active:
            z = self.meas[n]
            for k in np.flatnonzero(use[n]):
                g.add(self._measurement(n, k, z[k], noise))
        for k in range(self.f):
            g.add(state_prior_factor(self.state_key[k], np.zeros(4), self.prior_sig))
        if motion is not None:
            for k, dt in zip(motion.index, motion.dt_s):
                g.add(constant_velocity_factor(self.state_key[k], self.state_key[k + 1],
                                               float(dt), motion.sigma_a_mps2, motion.robust,
                                               motion.k if motion.robust else None))
        return g

    def ordering(self) -> gtsam.Ordering:
        """The elimination order: the states in time order, then the clock
        offsets and the poses.

        Every state touches every pose, and the motion factors chain the
        states: eliminated in this order each state's clique holds its
        neighbour and the poses, so elimination is linear in frames, with the
        poses in the root clique (their marginals come free). GTSAM's COLAMD
        order grew about as frames^2 here (10 nodes: 0.8 s at 3,000 frames,
        51 s at 24,000 for the marginals alone).
        """
        order = gtsam.Ordering()
        for k in self.state_key:
            order.push_back(k)
        for key in self.offset_key.values():
            order.push_back(key)
        for n in self.active:
            if n != self.ref:
                order.push_back(self.pose_key[n])
        return order

    def values(self, poses, states, offsets=None) -> gtsam.Values:
        v = gtsam.Values()
        for n in self.active:
            if n != self.ref:
                v.insert(self.pose_key[n], to_pose2(poses[n]))
        for n, key in self.offset_key.items():
            v.insert(key, np.array([0.0 if offsets is None else float(offsets[n])]))
        for k in range(self.f):
            v.insert(self.state_key[k], states[k])
        return v

    def current(self, res: gtsam.Values):
        """``(poses, states, offsets)`` of a GTSAM solution (offsets: name ->
        residual seconds, 0 for the nodes without one)."""
        poses = {n: (np.zeros(3) if n == self.ref else pose_array(res.atPose2(self.pose_key[n])))
                 for n in self.active}
        states = np.array([res.atVector(self.state_key[k]) for k in range(self.f)])
        offsets = {n: (float(res.atVector(self.offset_key[n])[0]) if n in self.offset_key
                       else 0.0) for n in self.active}
        return poses, states, offsets


def _whitened_sq(state, pose, z, sigmas):
    h, _ = measurement_model(state, pose)
    e = residual(h, z) / sigmas
    return np.sum(e**2, axis=-1)


def flag_outliers(graph, poses, states, offsets, has, sig, gate_probability):
    """name -> (F,) bool: detections whose whitened squared residual exceeds
    the chi-square(3) ``gate_probability`` quantile."""
    threshold = chi2_gate(gate_probability, 3)
    outliers = {}
    for n in graph.active:
        e2 = np.full(graph.f, 0.0)
        tau = 0.0 if offsets is None else float(offsets.get(n, 0.0))
        e2[has[n]] = _whitened_sq(shifted_states(states[has[n]], tau), poses[n],
                                  graph.meas[n][has[n]], sig)
        outliers[n] = has[n] & (e2 > threshold)
    return outliers


#: Sigma (m) of the tie of a frame refitted alone (:func:`exonerate_turns`)
#: to the robust pass's position: the motion factors cut an instant turn's
#: corner by a few centimetres; a ghost's range is off by metres.
TURN_POSITION_SIGMA_M = 0.05


def _frame_refit(graph, poses, states, offsets, use, rows, sig, prior_sig, gn_steps):
    """Each frame of ``rows`` fitted alone (no motion factors): Gauss-Newton
    on its detections ``use`` at the given poses and offsets, from
    ``states``, the velocity under the state prior and the position tied to
    its value in ``states`` with sigma :data:`TURN_POSITION_SIGMA_M`.
    Returns the whitened squared residual (the tie's included) and the
    number of detections per frame."""
    x = np.array(states[rows], dtype=float)
    p0 = x[:, :2].copy()
    w = 1.0 / np.asarray(prior_sig, dtype=float) ** 2
    w[:2] = 1.0 / TURN_POSITION_SIGMA_M**2
    for step in range(gn_steps + 1):
        a = np.tile(np.diag(w), (rows.size, 1, 1))
        b = -np.concatenate([x[:, :2] - p0, x[:, 2:]], axis=1) * w
        chi = np.sum((x[:, :2] - p0) ** 2, axis=1) * w[0]
        count = np.zeros(rows.size, dtype=int)
        for n in graph.active:
            ok = use[n][rows]
            tau = 0.0 if offsets is None else float(offsets.get(n, 0.0))
            h, jac = measurement_model(shifted_states(x[ok], tau), poses[n])
            e = residual(h, graph.meas[n][rows[ok]]) / sig
            j = jac / sig[:, None]
            j[:, :, 2:] += tau * j[:, :, :2]
            chi[ok] += np.sum(e**2, axis=1)
            count[ok] += 1
            a[ok] += np.swapaxes(j, 1, 2) @ j
            b[ok] -= (np.swapaxes(j, 1, 2) @ e[:, :, None])[:, :, 0]
        if step < gn_steps:
            x = x + np.linalg.solve(a, b[..., None])[..., 0]
    return chi, count


def exonerate_turns(graph, poses, states, offsets, has, outliers, sig, prior_sig,
                    gate_probability, gn_steps=3):
    """Unflag the detections of the frames that a new velocity explains
    (docs/CALIBRATION.md, "Sharp turns"). At an instant turn the motion factors smooth
    the velocity across the turn (and cut its corner by a few cm): every
    node's residual misfits, mostly in Doppler, although the detections agree
    with each other and with the track's position; a ghost disagrees with
    the position (its range is random). So a flagged frame is refitted alone
    (:func:`_frame_refit`: no motion factors, a free velocity, the position
    tied to the robust pass's): if its whitened squared residual is below the
    chi-square(3 m) ``gate_probability`` quantile (m >= 2 detections),
    the motion model misfit, not a detection, and none of its detections is
    an outlier. Returns the new outliers and the indices of those frames
    (measured: docs/CALIBRATION.md, "Sharp turns")."""
    flagged = np.zeros(graph.f, dtype=bool)
    for n in graph.active:
        flagged |= outliers[n]
    rows = np.flatnonzero(flagged)
    if rows.size == 0:
        return outliers, rows
    chi, count = _frame_refit(graph, poses, states, offsets, has, rows, sig, prior_sig, gn_steps)
    dof = 3 * count
    ok = (count >= 2) & (chi <= chi2_gate(gate_probability, np.maximum(dof, 1)))
    turn_frames = rows[ok]
    new = {}
    for n in graph.active:
        o = outliers[n].copy()
        o[turn_frames] = False
        new[n] = o
    return new, turn_frames


def flag_turns(motion: MotionSpec | None, norms: NDArray | None, gate_probability):
    """(G,) bool: motion factors whose whitened squared norm exceeds the
    chi-square(4) ``gate_probability`` quantile (a turn sharper than the
    white acceleration explains), or None without motion factors."""
    if motion is None or norms is None:
        return None
    return norms**2 > chi2_gate(gate_probability, 4)


def _node_covariances(marg, graph, covs, variances):
    """Each pose's marginal and offset variance into ``covs`` and
    ``variances``; returns the joint covariance (3M, 3M) of the M
    non-reference poses in ``graph.active`` order (cross-covariances
    included: the poses share every frame's state)."""
    others = [n for n in graph.active if n != graph.ref]
    for n in others:
        c = marg.marginalCovariance(graph.pose_key[n])
        covs[n] = 0.5 * (c + c.T)
        if n in graph.offset_key:
            variances[n] = float(marg.marginalCovariance(graph.offset_key[n])[0, 0])
    if not others:
        return np.zeros((0, 0))
    # The poses are the root clique of graph.ordering(): their joint is cheap.
    jm = marg.jointMarginalCovariance([graph.pose_key[n] for n in others])
    joint = np.block([[jm.at(graph.pose_key[a], graph.pose_key[b]) for b in others]
                      for a in others])
    return 0.5 * (joint + joint.T)


def eliminate_in_order(linear: gtsam.GaussianFactorGraph, order: gtsam.Ordering):
    """The linearized graph eliminated in ``order``: a Bayes tree whose
    ``marginalCovariance`` gives the marginals (raises RuntimeError on an
    indeterminant system)."""
    return linear.eliminateMultifrontal(order)


def assess(graph, final_graph, result, state_covariances, max_pose_variance,
           max_pose_condition, linear=None):
    """Marginal covariances, offset variances (name -> s^2, NaN where not
    estimated, 0 for the reference), the state marginals, the unobservable
    pose directions, why the elimination failed ("" when it did not: then
    the marginals are the dense Schur complement's) and the joint pose
    covariance (None when the elimination fails)."""
    ref, active = graph.ref, graph.active
    covs: dict[str, NDArray] = {ref: np.zeros((3, 3))}
    variances = {n: (0.0 if n == ref else float("nan")) for n in active}
    state_covs = np.full((graph.f, 4, 4), np.nan)
    unobservable: dict[str, NDArray] = {}
    failure = ""
    joint = None
    try:
        # The marginals from a Bayes tree in the graph's own order (linear in
        # frames; gtsam.Marginals would use COLAMD: JointGraph.ordering).
        lin = final_graph.linearize(result) if linear is None else linear
        marg = eliminate_in_order(lin, graph.ordering())
        joint = _node_covariances(marg, graph, covs, variances)
        if state_covariances:
            for k in range(graph.f):
                c = marg.marginalCovariance(graph.state_key[k])
                state_covs[k] = 0.5 * (c + c.T)
        for n in active:
            if n == ref:
                continue
            w, v = np.linalg.eigh(covs[n])
            bad = (w > max_pose_variance) | (w > max_pose_condition * max(w.min(), 1e-300))
            if np.any(bad):
                unobservable[n] = v[:, bad].T
    except RuntimeError as exc:
        failure = f"the marginals failed ({(str(exc).splitlines() or [type(exc).__name__])[0]})"
        covs.update(schur_covariances(final_graph, result, graph, unobservable,
                                      max_pose_condition))
    return covs, variances, state_covs, unobservable, failure, joint


def schur_covariances(final_graph, values, graph, unobservable, condition):
    """Pose information by a dense Schur complement of the linearized graph,
    for a singular system: the eigen-directions whose information is below
    ``1 / condition`` of the largest are unobservable; the covariance is the
    inverse on the rest, with ``inf`` on the diagonal of every component a
    null direction touches (NaN off the diagonal there). The clock offsets,
    if any, are eliminated with the states."""
    others = [n for n in graph.active if n != graph.ref]
    order = gtsam.Ordering()
    for n in others:
        order.push_back(graph.pose_key[n])
    for key in graph.offset_key.values():
        order.push_back(key)
    for k in graph.state_key:
        order.push_back(k)
    lam, _ = final_graph.linearize(values).hessian(order)
    p = 3 * len(others)
    a, b, c = lam[:p, :p], lam[:p, p:], lam[p:, p:]
    schur = a - b @ np.linalg.lstsq(c, b.T, rcond=None)[0]
    schur = 0.5 * (schur + schur.T)
    w, v = np.linalg.eigh(schur)
    null = w <= max(w.max(), 1e-300) / condition
    keep = ~null
    cov_all = (v[:, keep] / w[keep]) @ v[:, keep].T  # inverse on the observable part
    covs = {}
    for i, n in enumerate(others):
        rows = slice(3 * i, 3 * i + 3)
        cov = cov_all[rows, rows].copy()
        dirs = v[rows][:, null].T  # (m, 3) this node's part of each null vector
        dirs = dirs[np.linalg.norm(dirs, axis=1) > 1e-3]
        if dirs.size:
            unobservable[n] = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
            touched = np.any(np.abs(unobservable[n]) > 1e-3, axis=0)
            cov[touched, :] = np.nan
            cov[:, touched] = np.nan
            cov[touched, touched] = np.inf
        covs[n] = cov
    return covs
