"""Joint calibration graph: node poses and the target's states from the raw
measurements (docs/CONVENTIONS.md, "Pairwise self-calibration", last paragraph).

Variables: every node's ``Pose2`` but the reference's (S1, fixed at the
origin), and the target's state ``(x, y, vx, vy)`` at every frame that at
least two nodes detected. Factors:

- per node and frame, range + spatial frequency + Doppler: the reference
  node through ``factors.node_measurement_factor`` (known pose), the others
  through ``factors.pose_measurement_factor`` (form b), each whitened by
  ``factors.measurement_noise`` of the :class:`MeasurementNoise`, optionally under a Huber or Cauchy
  kernel against ghost detections;
- a weak prior per state (paper eq. 16 velocity prior, 3.5 m/s; a 1 km
  position prior that only keeps the system well posed);
- optionally, ``factors.constant_velocity_factor`` between consecutive frames.

The closed form (on each node's detections mapped to local xy, with a trimmed
refit that drops frames whose alignment residual is far above the median)
gives the initial poses, a pose graph over all node pairs when N > 2
(:mod:`.robust_start`); LM solves, after a numpy pre-solve of the same graph
(:mod:`.presolve`). With a robust kernel, detections whose whitened residual
exceeds the chi-square(3) ``outlier_probability`` quantile are flagged as outliers and a
final Gaussian LM pass on the inliers gives the estimate and
``gtsam.Marginals`` the covariances (a robust kernel's weights would inflate
them). When the marginals are singular or a pose variance exceeds
``max_pose_variance``, the result has ``success=False`` and names the
unobservable direction (e.g. a standing target: a node may turn about it).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from typing import Literal, Mapping

import gtsam
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.stats import chi2

from factors.gtsam_factors import (
    constant_velocity_factor,
    measurement_noise,
    node_measurement_factor,
    pose_measurement_factor,
    state_prior_factor,
)
from factors.models import measurement_model, residual
from factors.robust import ROBUST_K_DEFAULT

from ..errors import CalibrationError, MmsnapError, ValidationError
from ..data.noise import MeasurementNoise
from ..data.recording import Detections
from .._validation import as_float_array, check_finite, check_positive, check_shape
from .closed_form import DEFAULT_MIN_COMMON_FRAMES, DEFAULT_MIN_SPREAD_M
from .poses import pose_array, to_pose2
from .presolve import presolve as numpy_presolve
from .robust_start import starting_poses, starting_states

__all__ = ["DEFAULT_ROBUST_K", "JointCalibration", "joint_calibration"]

#: Default width of the robust kernels on the whitened 3-vector norm (GTSAM's
#: mEstimator ``k``): Huber 1.345, Cauchy 2.5; the project's one table,
#: :data:`factors.robust.ROBUST_K_DEFAULT`.
DEFAULT_ROBUST_K = ROBUST_K_DEFAULT


@dataclass(frozen=True, kw_only=True, slots=True)
class JointCalibration:
    """Result of :func:`joint_calibration`.

    poses, covariances : name -> (3,) pose and (3, 3) marginal covariance
        (body tangent) of every calibrated node; the reference's is zero.
    initial_poses : the closed-form starting poses.
    frames : (F,) int, the frames in the graph. states : (F, 4) the target
        states, global. state_covariances : (F, 4, 4) their marginals (NaN
        when the marginals failed).
    outliers : name -> (F,) bool, detections flagged as outliers (False where
        the node has no detection).
    unobservable : name -> (m, 3) unit directions (body tangent) along which
        the node's pose is not determined; empty when all is observable.
    unreachable : nodes left out (no common frames with the others).
    """

    reference: str
    poses: Mapping[str, NDArray]
    covariances: Mapping[str, NDArray]
    initial_poses: Mapping[str, NDArray]
    frames: NDArray
    states: NDArray
    state_covariances: NDArray
    outliers: Mapping[str, NDArray]
    success: bool
    message: str
    iterations: int = 0
    initial_error: float = float("nan")
    final_error: float = float("nan")
    unobservable: Mapping[str, NDArray] = field(default_factory=dict)
    unreachable: tuple[str, ...] = ()


def _detections_table(dets: Mapping[str, Detections]):
    out = {}
    for name, d in dets.items():
        if isinstance(d, Detections):
            fr, z = d.frame, d.measurements
        else:
            try:
                fr, z = d
            except (TypeError, ValueError):
                raise ValidationError(f"detections[{name!r}] must be Detections or a "
                                      f"(frame, measurements) pair") from None
            fr = np.asarray(fr)
            z = check_finite(check_shape(as_float_array(z, f"detections[{name!r}] measurements"),
                                         (fr.shape[0], 3), f"detections[{name!r}] measurements"),
                             f"detections[{name!r}] measurements")
        fr = np.asarray(fr, dtype=np.int64)
        if np.unique(fr).size != fr.size:
            raise CalibrationError(f"node {name}: several detections in one frame; the joint "
                                   f"calibration needs one target detection per node per frame")
        order = np.argsort(fr)
        out[str(name)] = (fr[order], np.asarray(z, dtype=float)[order])
    return out


def _noise_from_sigmas(sigmas: ArrayLike) -> MeasurementNoise:
    """The deprecated ``sigmas=`` (3,) as a :class:`MeasurementNoise`."""
    warnings.warn("joint_calibration(sigmas=...) is deprecated; pass "
                  "noise=MeasurementNoise(...)", DeprecationWarning, stacklevel=3)
    r, w, v = check_shape(as_float_array(sigmas, "sigmas"), (3,), "sigmas")
    return MeasurementNoise(range_m=r, omega_rad=w, doppler_mps=v)


def _validate(names, reference, noise, state_prior_sigmas, robust, motion, frame_period_s,
              outlier_probability):
    """Check the options; returns ``(reference, sigmas (3,), prior sigmas (4,))``."""
    if len(names) < 2:
        raise CalibrationError(f"a calibration needs at least two nodes, got {names!r}")
    ref = names[0] if reference is None else str(reference)
    if ref not in names:
        raise ValidationError(f"reference={ref!r} is not one of the nodes {names!r}")
    if not isinstance(noise, MeasurementNoise):
        raise ValidationError(f"noise must be a MeasurementNoise, got {noise!r}")
    prior_sig = check_positive(check_shape(as_float_array(state_prior_sigmas, "state_prior_sigmas"),
                                           (4,), "state_prior_sigmas"), "state_prior_sigmas")
    if robust not in (None, "huber", "cauchy"):
        raise ValidationError(f"robust={robust!r} must be None, 'huber' or 'cauchy'")
    if motion and frame_period_s is None:
        raise ValidationError("motion=True needs frame_period_s")
    if not 0 < outlier_probability < 1:
        raise ValidationError(f"outlier_probability must lie in (0, 1), got {outlier_probability!r}")
    return ref, noise.sigmas, prior_sig


def _check_count(value, name: str, minimum: int = 1) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise ValidationError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


def _validate_numbers(sig, robust_k, motion, frame_period_s, sigma_a_mps2, max_motion_gap_frames,
                      max_iterations, max_pose_variance, max_pose_condition):
    """Check the numeric options at the boundary (issue 13: zero or NaN
    sigma_a / frame period, k <= 0, vanishing sigmas reached GTSAM and numpy
    as their own errors)."""
    if robust_k is not None:
        check_positive(robust_k, "robust_k")
    if frame_period_s is not None:
        check_positive(frame_period_s, "frame_period_s")
    if motion:
        check_positive(sigma_a_mps2, "sigma_a_mps2")
    _check_count(max_motion_gap_frames, "max_motion_gap_frames")
    _check_count(max_iterations, "max_iterations")
    check_positive(max_pose_variance, "max_pose_variance")
    check_positive(max_pose_condition, "max_pose_condition")
    with np.errstate(over="ignore", divide="ignore"):
        info = 1.0 / np.asarray(sig, dtype=float) ** 2
    if not np.all(np.isfinite(info)) or np.any(info > 1e250):
        raise ValidationError(f"noise sigmas {tuple(float(v) for v in sig)} are too small: "
                              f"their information 1/sigma^2 overflows")


def _frame_table(dets, names, min_common_frames):
    """Frames seen by at least two nodes, and name -> (F, 3) measurements
    with NaN rows where a node saw nothing."""
    all_frames = np.unique(np.concatenate([d[0] for d in dets.values()]))
    seen = np.zeros((len(names), all_frames.size), dtype=bool)
    for i, n in enumerate(names):
        seen[i] = np.isin(all_frames, dets[n][0])
    frames = all_frames[seen.sum(0) >= 2]
    if frames.size < max(min_common_frames, 3):
        raise CalibrationError(f"too few frames seen by two nodes: {frames.size} < "
                               f"min_common_frames={max(min_common_frames, 3)}")
    meas_f = {}
    for n in names:
        z = np.full((frames.size, 3), np.nan)
        idx = np.searchsorted(dets[n][0], frames)
        idx = np.clip(idx, 0, dets[n][0].size - 1)
        hit = dets[n][0][idx] == frames
        z[hit] = dets[n][1][idx[hit]]
        meas_f[n] = z
    return frames, meas_f


def _start_poses(meas_f, names, ref, initial_poses, min_common_frames, min_spread_m):
    """The given starting poses (validated), else the robust closed form's."""
    if initial_poses is None:
        init, unreachable = starting_poses(meas_f, names, ref, min_common_frames, min_spread_m)
    else:
        init = {}
        for n in names:
            if n == ref:
                continue
            if n not in initial_poses:
                raise ValidationError(f"initial_poses has no pose for node {n!r}")
            init[n] = check_finite(check_shape(as_float_array(initial_poses[n],
                                                              f"initial_poses[{n!r}]"), (3,),
                                               f"initial_poses[{n!r}]"), f"initial_poses[{n!r}]")
        unreachable = ()
    init[ref] = np.zeros(3)
    return init, unreachable


def _restrict(frames, meas_f, active, min_common_frames):
    """Keep the frames still seen by two active nodes."""
    n_seen = sum(np.isfinite(meas_f[n][:, 0]).astype(int) for n in active)
    keep = n_seen >= 2
    frames = frames[keep]
    meas_f = {n: meas_f[n][keep] for n in active}
    if frames.size < max(min_common_frames, 3):
        raise CalibrationError(f"too few frames seen by two calibrated nodes: {frames.size}")
    return frames, meas_f


def _motion_spec(frames, motion, frame_period_s, max_motion_gap_frames, sigma_a_mps2):
    """``(index, dt_s, sigma_a)`` of the constant-velocity factors, or None."""
    if not motion:
        return None
    gaps = np.diff(frames)
    mi = np.flatnonzero(gaps <= max_motion_gap_frames)
    return (mi, gaps[mi] * float(frame_period_s), float(sigma_a_mps2))


class _Graph:
    """The joint calibration graph in GTSAM: keys, factors and values."""

    def __init__(self, meas_f, active, ref, prior_sig, motion_spec):
        self.meas, self.active, self.ref = meas_f, active, ref
        self.prior_sig, self.motion = prior_sig, motion_spec
        self.f = next(iter(meas_f.values())).shape[0]
        self.pose_key = {n: gtsam.symbol("x", i) for i, n in enumerate(active)}
        self.state_key = [gtsam.symbol("v", k) for k in range(self.f)]

    def build(self, noise, use) -> gtsam.NonlinearFactorGraph:
        g = gtsam.NonlinearFactorGraph()
        for n in self.active:
            z = self.meas[n]
            for k in np.flatnonzero(use[n]):
                if n == self.ref:
                    g.add(node_measurement_factor(self.state_key[k], np.zeros(3), z[k], noise))
                else:
                    g.add(pose_measurement_factor(self.pose_key[n], self.state_key[k], z[k], noise))
        for k in range(self.f):
            g.add(state_prior_factor(self.state_key[k], np.zeros(4), self.prior_sig))
        if self.motion is not None:
            for k, dt in zip(self.motion[0], self.motion[1]):
                g.add(constant_velocity_factor(self.state_key[k], self.state_key[k + 1],
                                               float(dt), self.motion[2]))
        return g

    def ordering(self) -> gtsam.Ordering:
        """The elimination order: the states in time order, then the poses.

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
        for n in self.active:
            if n != self.ref:
                order.push_back(self.pose_key[n])
        return order

    def values(self, poses, states) -> gtsam.Values:
        v = gtsam.Values()
        for n in self.active:
            if n != self.ref:
                v.insert(self.pose_key[n], to_pose2(poses[n]))
        for k in range(self.f):
            v.insert(self.state_key[k], states[k])
        return v

    def current(self, res: gtsam.Values):
        poses = {n: (np.zeros(3) if n == self.ref else pose_array(res.atPose2(self.pose_key[n])))
                 for n in self.active}
        states = np.array([res.atVector(self.state_key[k]) for k in range(self.f)])
        return poses, states


def _whitened_sq(state, pose, z, sigmas):
    h, _ = measurement_model(state, pose)
    e = residual(h, z) / sigmas
    return np.sum(e**2, axis=-1)


def _flag_outliers(graph, poses, states, has, sig, outlier_probability):
    threshold = chi2.ppf(1.0 - outlier_probability, 3)
    outliers = {}
    for n in graph.active:
        e2 = np.full(graph.f, 0.0)
        e2[has[n]] = _whitened_sq(states[has[n]], poses[n], graph.meas[n][has[n]], sig)
        outliers[n] = has[n] & (e2 > threshold)
    return outliers


class _Breakdown(Exception):
    """The estimation broke down (joint_calibration returns success=False)."""


#: Numerical errors of GTSAM and numpy that mean the estimation broke down
#: (not a bad argument: those are checked first): success=False, not a raise.
_NUMERICAL_ERRORS = (_Breakdown, RuntimeError, ValueError, IndexError, ArithmeticError,
                     np.linalg.LinAlgError)


def _refine(fg, values, params, presolved, order, rel_tol=1e-5):
    """GTSAM's final refinement: from a pre-solved point, Gauss-Newton steps
    by GTSAM's own elimination (a GTSAM LM iteration costs several times the
    elimination here, measured: docs/CALIBRATION.md, "Speed at scale"); a
    step whose linearized decrease is at most ``rel_tol`` of the error is
    taken as converged (no further evaluation of the graph); a step that
    does not lower the error hands over to GTSAM's LM, which also runs when
    not pre-solved. Returns ``(values, iterations, error, linear)`` with
    ``linear`` the graph linearized within that converged step (for the
    marginals) or None."""
    if presolved:
        error = None
        for it in range(params.getMaxIterations()):
            linear = fg.linearize(values)
            delta = linear.optimize(order)
            at_zero = linear.error(gtsam.VectorValues.Zero(delta))
            after = linear.error(delta)
            new = values.retract(delta)
            if at_zero - after <= rel_tol * at_zero:
                return new, it + 1, float(after), linear
            error = fg.error(values) if error is None else error
            new_error = fg.error(new)
            if not new_error < error:
                break
            values, error = new, new_error
    params.setOrdering(order)
    opt = gtsam.LevenbergMarquardtOptimizer(fg, values, params)
    result = opt.optimize()
    return result, int(opt.iterations()), float(fg.error(result)), None


def _robust_pass(graph, start, x0, sig, robust, k, presolve_first, params, common):
    """The first pass (under the kernel, if any): the numpy pre-solve, then
    GTSAM only when the pre-solve did not converge (the pre-solve minimizes
    the same cost: its optimum is GTSAM's). Returns ``(poses, states,
    GTSAM iterations, initial_error)``."""
    has = {n: np.isfinite(graph.meas[n][:, 0]) for n in graph.active}
    report: dict = {}
    if presolve_first:
        start, x0 = numpy_presolve(graph.meas, start, x0, robust=robust,
                                   k=k if k is not None else 1.0, report=report, **common)
        if report["converged"]:
            return start, x0, 0, report["initial_cost"]
    fg = graph.build(measurement_noise(sig, robust, k), has)
    initial_error = report.get("initial_cost")
    values = graph.values(start, x0)
    if initial_error is None:
        initial_error = float(fg.error(values))
    result, iterations, _, _ = _refine(fg, values, params, presolve_first, graph.ordering())
    poses, states = graph.current(result)
    return poses, states, iterations, initial_error


def _solve(graph, start, x0, sig, prior_sig, robust, k, presolve_first, max_iterations,
           outlier_probability):
    """Robust pass (numpy pre-solve; GTSAM when needed), outliers, then a
    Gaussian pass on the inliers refined by GTSAM. Returns the final graph
    and values and a summary."""
    has = {n: np.isfinite(graph.meas[n][:, 0]) for n in graph.active}
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(int(max_iterations))
    common = dict(names=graph.active, reference=graph.ref, sigmas=sig, prior_sigmas=prior_sig,
                  motion=graph.motion)
    poses, states, iterations, initial_error = _robust_pass(graph, start, x0, sig, robust, k,
                                                            presolve_first, params, common)
    outliers = _flag_outliers(graph, poses, states, has, sig, outlier_probability)
    inl = {n: has[n] & ~outliers[n] for n in graph.active} if robust is not None else has
    starved = [n for n in graph.active if n != graph.ref and not inl[n].any()]
    if starved:
        raise _Breakdown(f"every detection of {', '.join(starved)} is an outlier: no pose "
                         f"left to estimate")
    if robust is not None and presolve_first:
        poses, states = numpy_presolve(graph.meas, poses, states, robust=None, k=1.0, use=inl,
                                       **common)
    fg = graph.build(measurement_noise(sig), inl)
    result, more, final_error, linear = _refine(fg, graph.values(poses, states), params,
                                                presolve_first, graph.ordering())
    return fg, result, dict(outliers=outliers, iterations=iterations + more,
                            initial_error=initial_error, final_error=final_error, linear=linear)


def _bayes_tree(linear: gtsam.GaussianFactorGraph, order: gtsam.Ordering):
    """The linearized graph eliminated in ``order`` (raises RuntimeError on an
    indeterminant system)."""
    return linear.eliminateMultifrontal(order)


def _assess(graph, final_graph, result, state_covariances, max_pose_variance,
            max_pose_condition, linear=None):
    """Marginal covariances and the unobservable pose directions; the dense
    Schur complement when ``gtsam.Marginals`` fails."""
    ref, active = graph.ref, graph.active
    covs: dict[str, NDArray] = {ref: np.zeros((3, 3))}
    state_covs = np.full((graph.f, 4, 4), np.nan)
    unobservable: dict[str, NDArray] = {}
    notes = []
    try:
        # The marginals from a Bayes tree in the graph's own order (linear in
        # frames; gtsam.Marginals would use COLAMD: _Graph.ordering).
        lin = final_graph.linearize(result) if linear is None else linear
        marg = _bayes_tree(lin, graph.ordering())
        for n in active:
            if n != ref:
                c = marg.marginalCovariance(graph.pose_key[n])
                covs[n] = 0.5 * (c + c.T)
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
        notes.append(f"marginals failed ({str(exc).splitlines()[0]})")
        covs.update(_schur_covariances(final_graph, result, active, ref, graph.pose_key,
                                       graph.state_key, unobservable, max_pose_condition))
    return covs, state_covs, unobservable, notes


def _message(active, f, outliers, iterations, notes, unobservable, unreachable, ref):
    notes = list(notes)
    for n, dirs in unobservable.items():
        txt = ", ".join("(" + ", ".join(f"{c:+.2f}" for c in d) + ")" for d in dirs)
        notes.append(f"pose of {n} is not observable along {txt} (dx_b, dy_b, dphi)")
    if unreachable:
        notes.append(f"no common frames linking {', '.join(unreachable)} to {ref}")
    n_out = sum(int(o.sum()) for o in outliers.values())
    msg = (f"joint calibration of {len(active)} nodes on {f} frames, {n_out} outlier "
           f"detection(s), {iterations} LM iterations")
    if notes:
        msg += "; " + "; ".join(notes)
    return msg


def joint_calibration(
    detections: Mapping[str, Detections],
    *,
    reference: str | None = None,
    initial_poses: Mapping[str, ArrayLike] | None = None,
    noise: MeasurementNoise = MeasurementNoise(),
    robust: Literal["huber", "cauchy"] | None = "cauchy",
    robust_k: float | None = None,
    motion: bool = False,
    frame_period_s: float | None = None,
    sigma_a_mps2: float = 1.0,
    max_motion_gap_frames: int = 3,
    state_prior_sigmas: ArrayLike = (1e3, 1e3, 3.5, 3.5),
    outlier_probability: float = 1e-3,
    min_common_frames: int = DEFAULT_MIN_COMMON_FRAMES,
    min_spread_m: float = DEFAULT_MIN_SPREAD_M,
    max_pose_variance: float = 1.0,
    max_pose_condition: float = 1e4,
    max_iterations: int = 50,
    presolve: bool = True,
    state_covariances: bool = False,
    sigmas: ArrayLike | None = None,
) -> JointCalibration:
    """Refine node poses jointly with the target's states (module doc).

    Parameters
    ----------
    detections : name -> Detections (or ``(frame (K,), measurements (K, 3))``)
        One detection of the common target per node per frame, frames
        already corrected for each node's lag. The first node is the
        reference unless ``reference`` names another.
    initial_poses : name -> (3,), optional
        Starting poses (the reference's is ignored); by default the trimmed
        closed form (and a pose graph for N > 2).
    noise : measurement noise of the detections (default: the paper's).
    robust, robust_k : kernel against ghost detections (None: Gaussian).
        Default k (:data:`DEFAULT_ROBUST_K`): Huber 1.345, Cauchy 2.5 (on
        the whitened 3-vector norm).
    motion : add constant-velocity factors between consecutive frames no
        more than ``max_motion_gap_frames`` apart; needs ``frame_period_s``.
    sigma_a_mps2 : white-acceleration sigma of the motion factors.
    state_prior_sigmas : (4,) sigmas of the zero-mean state prior.
    outlier_probability : a detection whose whitened squared residual exceeds
        the chi-square(3) ``1 - outlier_probability`` quantile is an outlier.
    min_common_frames : fewer frames seen by two nodes raise CalibrationError.
    max_pose_variance : a pose marginal variance (m^2 or rad^2) above this
        means that the pose is not determined: ``success=False``.
    max_pose_condition : so does an eigenvalue of a pose covariance more
        than this times its smallest (a standing target leaves S2 free to
        turn about it, up to the faint hold of the velocity prior through the
        Doppler: variances of 1e-6 against 0.2 in a test).
    presolve : run the numpy pre-solve (:mod:`.presolve`, same models)
        before each GTSAM LM pass; LM then needs one or two iterations.
        False: LM from the closed form (slower, same optimum).
    state_covariances : also return each frame's state marginal (slow for
        long sequences; NaN otherwise).
    sigmas : deprecated: (3,) ``(range_m, omega_rad, doppler_mps)``, read as
        ``noise`` (DeprecationWarning); pass ``noise=MeasurementNoise(...)``.

    Returns
    -------
    JointCalibration
    """
    if sigmas is not None:
        noise = _noise_from_sigmas(sigmas)
    dets = _detections_table(detections)
    names = list(dets)
    ref, sig, prior_sig = _validate(names, reference, noise, state_prior_sigmas, robust, motion,
                                    frame_period_s, outlier_probability)
    _validate_numbers(sig, robust_k, motion, frame_period_s, sigma_a_mps2, max_motion_gap_frames,
                      max_iterations, max_pose_variance, max_pose_condition)
    frames, meas_f = _frame_table(dets, names, min_common_frames)
    init, unreachable = _start_poses(meas_f, names, ref, initial_poses, min_common_frames,
                                     min_spread_m)
    active = [n for n in names if n not in unreachable]
    frames, meas_f = _restrict(frames, meas_f, active, min_common_frames)
    x0 = starting_states(meas_f, init, active, sig, prior_sig[2])
    graph = _Graph(meas_f, active, ref, prior_sig,
                   _motion_spec(frames, motion, frame_period_s, max_motion_gap_frames,
                                sigma_a_mps2))
    k = None if robust is None else (robust_k if robust_k is not None else DEFAULT_ROBUST_K[robust])
    try:
        return _estimate(graph, frames, init, x0, unreachable, sig, prior_sig, robust, k, presolve,
                         max_iterations, outlier_probability, state_covariances,
                         max_pose_variance, max_pose_condition)
    except MmsnapError:
        raise
    except _NUMERICAL_ERRORS as exc:
        return _broken_down(graph, frames, init, x0, unreachable, exc)


def _estimate(graph, frames, init, x0, unreachable, sig, prior_sig, robust, k, presolve,
              max_iterations, outlier_probability, state_covariances, max_pose_variance,
              max_pose_condition) -> JointCalibration:
    """Solve, assess, and the result (the numerical part of
    :func:`joint_calibration`)."""
    active, ref = graph.active, graph.ref
    final_graph, result, run = _solve(graph, {n: init[n] for n in active}, x0, sig, prior_sig,
                                      robust, k, presolve, max_iterations, outlier_probability)
    poses, states = graph.current(result)
    covs, state_covs, unobservable, notes = _assess(graph, final_graph, result, state_covariances,
                                                    max_pose_variance, max_pose_condition,
                                                    run["linear"])
    msg = _message(active, frames.size, run["outliers"], run["iterations"], notes, unobservable,
                   unreachable, ref)
    return JointCalibration(
        reference=ref, poses=poses, covariances=covs,
        initial_poses={n: np.asarray(init[n], dtype=float) for n in active}, frames=frames,
        states=states, state_covariances=state_covs, outliers=run["outliers"],
        success=not (unobservable or unreachable), message=msg, iterations=run["iterations"],
        initial_error=run["initial_error"], final_error=run["final_error"],
        unobservable=unobservable, unreachable=tuple(unreachable))


def _broken_down(graph, frames, init, x0, unreachable, exc) -> JointCalibration:
    """The result when the estimation broke down: the starting poses and
    states, NaN covariances, ``success=False`` and the reason."""
    active, ref = graph.active, graph.ref
    reason = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
    if not isinstance(exc, _Breakdown):
        reason = f"{type(exc).__name__}: {reason}"
    nan3 = np.full((3, 3), np.nan)
    return JointCalibration(
        reference=ref, poses={n: np.asarray(init[n], dtype=float) for n in active},
        covariances={n: (np.zeros((3, 3)) if n == ref else nan3.copy()) for n in active},
        initial_poses={n: np.asarray(init[n], dtype=float) for n in active}, frames=frames,
        states=np.asarray(x0, dtype=float), state_covariances=np.full((graph.f, 4, 4), np.nan),
        outliers={n: np.zeros(graph.f, dtype=bool) for n in active}, success=False,
        message=(f"joint calibration of {len(active)} nodes on {frames.size} frames failed: "
                 f"{reason}"),
        iterations=0, initial_error=float("nan"), final_error=float("nan"), unobservable={},
        unreachable=tuple(unreachable))


def _schur_covariances(graph, values, active, ref, pose_key, state_key, unobservable,
                       condition):
    """Pose information by a dense Schur complement of the linearized graph,
    for a singular system: the eigen-directions whose information is below
    ``1 / condition`` of the largest are unobservable; the covariance is the
    inverse on the rest, with ``inf`` on the diagonal of every component a
    null direction touches (NaN off the diagonal there)."""
    others = [n for n in active if n != ref]
    order = gtsam.Ordering()
    for n in others:
        order.push_back(pose_key[n])
    for k in state_key:
        order.push_back(k)
    lam, _ = graph.linearize(values).hessian(order)
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
