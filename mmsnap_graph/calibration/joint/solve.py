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
exceeds the chi-square(3) ``gate_probability`` quantile are flagged as outliers and a
final Gaussian LM pass on the inliers gives the estimate and
``gtsam.Marginals`` the covariances (a robust kernel's weights would inflate
them). When the marginals are singular or a pose variance exceeds
``max_pose_variance``, the result has status ``NOT_OBSERVABLE`` and names the
unobservable direction (e.g. a standing target: a node may turn about it).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Mapping

import gtsam
import numpy as np
from numpy.typing import ArrayLike, NDArray

from factors.gtsam_factors import measurement_noise

from ...errors import CalibrationError, MmsnapError, ValidationError
from ...data.calibration_facts import (
    CalibrationFact,
    CalibrationStatus,
    JointFit,
    PoseCovariance,
    PoseNotObservable,
    RangeOffsetEstimated,
    SolveBrokeDown,
)
from ...data.noise import MeasurementNoise
from ...data.recording import Detections
from ..._validation import as_float_array, check_finite, check_pose, check_positive, check_shape
from .graph import (
    JointGraph,
    assess,
    exonerate_turns,
    flag_outliers,
    flag_turns,
    motion_spec,
)
from .options import JointOptions
from .covariance import BlockCovariance, bandwidth_frames, block_covariance
from .presolve import RANGE_OFFSET, PresolveProblem, motion_norms
from .presolve import presolve as numpy_presolve
from .robust_start import starting_poses, starting_states

__all__ = ["JointCalibration", "joint_calibration"]


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
    status : :class:`~mmsnap_graph.data.calibration_facts.CalibrationStatus`
        (``OK``: :attr:`success`): ``NODES_UNREACHABLE`` when a node has no
        common frames with the others, ``NOT_OBSERVABLE`` when a pose is not
        determined along some direction, ``SOLVE_FAILED`` when the solve
        broke down.
    facts : what the solve found (:mod:`mmsnap_graph.data.calibration_facts`):
        a ``JointFit`` (nodes, frames, outliers, steps), one
        ``PoseCovariance`` (how the covariances were computed), a
        ``RangeOffsetEstimated`` with a range-offset prior, a
        ``PoseNotObservable`` per such node, a ``SolveBrokeDown`` when it
        broke down.
    unobservable : name -> (m, 3) unit directions (body tangent) along which
        the node's pose is not determined; empty when all is observable.
    unreachable : nodes left out (no common frames with the others).
    time_offset_s : name -> clock offset in seconds (node time + offset =
        reference time; 0 for the reference): ``-lag * frame_period_s`` plus
        the estimated fraction when ``time_offsets=True``, else the lag's.
    time_offset_variances : name -> its marginal variance (s^2; 0 for the
        reference, NaN where not estimated).
    turns : motion factors left out of the final pass as sharp turns.
    joint_covariance : (3M, 3M) covariance of the M non-reference poses in
        ``joint_order`` with their cross-covariances (the poses share the
        target's states, so a network's pose errors are correlated); None
        when the marginals failed.
    range_offset_m, range_offset_variance : the estimated range offset
        (reflection depth, m) and its variance (m^2) with
        ``JointOptions.range_offset_prior_m``; NaN without.
    model_covariances : the graph's marginals (``covariances`` holds the
        reported ones: with the range offset marginalized and, with
        ``JointOptions.covariance="long_run"``, widened where the data show
        correlated errors or model error).
    lag_frames : name -> the whole-frame lag of the final solve: the
        ``lag_frames`` given, or one frame from it for a node whose clock
        offset came out more than :data:`LAG_RECENTRE_FRACTION` of a frame
        beyond it (then the detections' frames were shifted to match).
    pose_block : the :class:`~.covariance.BlockCovariance` the covariances
        come from (:mod:`.windowed` combines them); None: the marginals.
    """

    reference: str
    poses: Mapping[str, NDArray]
    covariances: Mapping[str, NDArray]
    initial_poses: Mapping[str, NDArray]
    frames: NDArray
    states: NDArray
    state_covariances: NDArray
    outliers: Mapping[str, NDArray]
    status: CalibrationStatus
    facts: tuple[CalibrationFact, ...] = ()
    iterations: int = 0
    initial_error: float = float("nan")
    final_error: float = float("nan")
    unobservable: Mapping[str, NDArray] = field(default_factory=dict)
    unreachable: tuple[str, ...] = ()
    time_offset_s: Mapping[str, float] = field(default_factory=dict)
    time_offset_variances: Mapping[str, float] = field(default_factory=dict)
    turns: int = 0
    joint_covariance: NDArray | None = None
    joint_order: tuple[str, ...] = ()
    lag_frames: Mapping[str, int] = field(default_factory=dict)
    range_offset_m: float = float("nan")
    range_offset_variance: float = float("nan")
    model_covariances: Mapping[str, NDArray] = field(default_factory=dict)
    pose_block: BlockCovariance | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "status", CalibrationStatus(self.status))
        object.__setattr__(self, "facts", tuple(self.facts))

    @property
    def success(self) -> bool:
        """``status is CalibrationStatus.OK``."""
        return self.status is CalibrationStatus.OK


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


@dataclass(frozen=True, slots=True)
class _Inputs:
    """The data of one solve (the arguments of :func:`joint_calibration`
    besides the options), checked."""

    detections: Mapping[str, tuple[NDArray, NDArray]]
    reference: str
    initial_poses: Mapping[str, NDArray] | None
    sigmas: NDArray
    frame_period_s: float | None
    lag_frames: Mapping[str, int]


def _inputs(detections, reference, initial_poses, noise, frame_period_s, lag_frames,
            options: JointOptions) -> _Inputs:
    """Check the data against each other and the options."""
    if not isinstance(options, JointOptions):
        raise ValidationError(f"options must be a JointOptions, got {options!r}")
    dets = _detections_table(detections)
    names = list(dets)
    if len(names) < 2:
        raise CalibrationError(f"a calibration needs at least two nodes, got {names!r}")
    ref = names[0] if reference is None else str(reference)
    if ref not in names:
        raise ValidationError(f"reference={ref!r} is not one of the nodes {names!r}")
    if not isinstance(noise, MeasurementNoise):
        raise ValidationError(f"noise must be a MeasurementNoise, got {noise!r}")
    sig = noise.sigmas
    with np.errstate(over="ignore", divide="ignore"):
        info = 1.0 / np.asarray(sig, dtype=float) ** 2
    if not np.all(np.isfinite(info)) or np.any(info > 1e250):
        raise ValidationError(f"noise sigmas {tuple(float(v) for v in sig)} are too small: "
                              f"their information 1/sigma^2 overflows")
    if frame_period_s is not None:
        frame_period_s = float(check_positive(frame_period_s, "frame_period_s"))
    elif options.motion:
        raise ValidationError("motion=True needs frame_period_s (JointOptions.motion)")
    lags = {}
    for n, lag in dict(lag_frames or {}).items():
        if str(n) not in names:
            raise ValidationError(f"lag_frames names an unknown node {n!r}")
        if isinstance(lag, bool) or not isinstance(lag, (int, np.integer)):
            raise ValidationError(f"lag_frames[{n!r}] must be an integer, got {lag!r}")
        lags[str(n)] = int(lag)
    if any(lags.values()) and frame_period_s is None:
        raise ValidationError("lag_frames needs frame_period_s")
    return _Inputs(dets, ref, initial_poses, sig, frame_period_s, lags)


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
            init[n] = check_pose(initial_poses[n], f"initial_poses[{n!r}]")
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


class _Breakdown(Exception):
    """The estimation broke down (joint_calibration returns SOLVE_FAILED)."""


#: Numerical errors of GTSAM and numpy that mean the estimation broke down
#: (not a bad argument: those are checked first): SOLVE_FAILED, not a raise.
_NUMERICAL_ERRORS = (_Breakdown, RuntimeError, ValueError, IndexError, ArithmeticError,
                     np.linalg.LinAlgError)


def _refine(fg, values, params, presolved, order, rel_tol=1e-5):
    """GTSAM's final refinement: from a pre-solved point, Gauss-Newton steps
    by GTSAM's own elimination (a GTSAM LM iteration costs several times the
    elimination here, measured: docs/validation/calibration.md, "Speed at scale"); a
    step whose linearized decrease is at most ``rel_tol`` of the error is
    taken as converged (no further evaluation of the graph); a step that
    does not lower the error hands over to GTSAM's LM, which also runs when
    not pre-solved. Returns ``(values, iterations, error, linear)`` with
    ``linear`` the graph linearized within that converged step (for the
    marginals) or None. ``order``: the elimination order of every step
    (:meth:`JointGraph.ordering`)."""
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


def _presolve(graph, start, sig, options: JointOptions, *, kernel: bool, motion, use=None,
              report=None):
    """The numpy pre-solve of the graph from ``start = (poses, states,
    offsets)`` (the clock offsets are estimated when the graph has them),
    under the options' robust kernel when ``kernel``; returns ``(poses,
    states, offsets)``."""
    poses, states, offsets = start
    problem = _problem(graph, sig, options, kernel=kernel, motion=motion, use=use)
    given = dict(offsets) if graph.timed else None
    if problem.range_offset is not None:  # the offset beyond the shift applied so far
        given = {**(given or {}), RANGE_OFFSET: 0.0}
    out = numpy_presolve(problem, poses, states, offsets=given, report=report)
    if problem.range_offset is not None:
        graph.shift_ranges(out[2].pop(RANGE_OFFSET))
    return out if graph.timed else (out[0], out[1], offsets)


def _problem(graph, sig, options: JointOptions, *, kernel: bool, motion, use=None
             ) -> PresolveProblem:
    """The graph as the numpy pre-solve sees it; the range offset's prior
    is on the offset beyond the shift already applied to the ranges."""
    prior = options.range_offset_prior_m
    return PresolveProblem(
        measurements=graph.meas, names=graph.active, reference=graph.ref, sigmas=sig,
        prior_sigmas=np.asarray(options.state_prior_sigmas), use=use,
        robust=options.robust if kernel else None,
        k=options.kernel_k if kernel and options.robust is not None else 1.0,
        motion=None if motion is None else motion.as_tuple(),
        range_offset=None if prior is None else (prior[0] - graph.range_offset_m, prior[1]))


def _robust_pass(graph, start, sig, options: JointOptions, params):
    """The first pass (under the kernel, if any) from ``start = (poses,
    states, offsets)``: the numpy pre-solve, then GTSAM only when the
    pre-solve did not converge (the pre-solve minimizes the same cost: its
    optimum is GTSAM's). Returns ``(poses, states, offsets, GTSAM
    iterations, initial_error)``."""
    has = {n: np.isfinite(graph.meas[n][:, 0]) for n in graph.active}
    report: dict = {}
    if options.presolve:
        start = _presolve(graph, start, sig, options, kernel=True, motion=graph.motion,
                          report=report)
        graph.presolve_steps.append((report["steps"], report["converged"]))
        if report["converged"]:
            return (*start, 0, report["initial_cost"])
    fg = graph.build(measurement_noise(sig, options.robust, options.kernel_k), has)
    initial_error = report.get("initial_cost")
    values = graph.values(*start)
    if initial_error is None:
        initial_error = float(fg.error(values))
    result, iterations, _, _ = _refine(fg, values, params, options.presolve, graph.ordering())
    poses, states, offsets = graph.current(result)
    return poses, states, offsets, iterations, initial_error


def _final_motion(graph, states, robust, turn_frames, gate_probability):
    """The motion factors of the final Gaussian pass: without the turns,
    which would otherwise pull the states off the detections -- the factors
    into and out of the frames :func:`exonerate_turns` found, and under a
    motion kernel the factors the robust pass found far beyond their white
    acceleration (:func:`flag_turns`); and the number of factors left out."""
    if graph.motion is None:
        return None, 0
    m = graph.motion
    turns = np.isin(m.index, turn_frames) | np.isin(m.index + 1, turn_frames)
    if robust is not None and m.robust is not None:
        turns |= flag_turns(m, motion_norms(states, m.as_tuple()), gate_probability)
    return m.subset(~turns, None), int(turns.sum())


def _solve(graph, start, x0, sig, options: JointOptions):
    """Robust pass (numpy pre-solve; GTSAM when needed), outliers, then a
    Gaussian pass on the inliers refined by GTSAM. Returns the final graph
    and values and a summary."""
    has = {n: np.isfinite(graph.meas[n][:, 0]) for n in graph.active}
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(options.max_iterations)
    robust, gate_probability = options.robust, options.gate_probability
    prior_sig = np.asarray(options.state_prior_sigmas)
    offsets = {n: 0.0 for n in graph.active}
    poses, states, offsets, iterations, initial_error = _robust_pass(
        graph, (start, x0, offsets), sig, options, params)
    outliers = flag_outliers(graph, poses, states, offsets, has, sig, gate_probability)
    turn_frames = np.zeros(0, dtype=int)
    if graph.motion is not None:
        outliers, turn_frames = exonerate_turns(graph, poses, states, offsets, has, outliers,
                                                sig, prior_sig, gate_probability)
    inl = {n: has[n] & ~outliers[n] for n in graph.active} if robust is not None else has
    starved = [n for n in graph.active if n != graph.ref and not inl[n].any()]
    if starved:
        raise _Breakdown(f"every detection of {', '.join(starved)} is an outlier: no pose "
                         f"left to estimate")
    motion, n_turns = _final_motion(graph, states, robust, turn_frames, gate_probability)
    if (robust is not None or n_turns or options.range_offset_prior_m is not None) \
            and options.presolve:
        report: dict = {}
        poses, states, offsets = _presolve(graph, (poses, states, offsets), sig, options,
                                           kernel=False, motion=motion, use=inl, report=report)
        graph.presolve_steps.append((report["steps"], report["converged"]))
    fg = graph.build(measurement_noise(sig), inl, motion)
    result, more, final_error, linear = _refine(fg, graph.values(poses, states, offsets),
                                                params, options.presolve, graph.ordering())
    return fg, result, dict(outliers=outliers, iterations=iterations + more, turns=n_turns,
                            initial_error=initial_error, final_error=final_error, linear=linear,
                            use=inl, motion=motion)


def joint_calibration(
    detections: Mapping[str, Detections],
    options: JointOptions | None = None,
    *,
    reference: str | None = None,
    initial_poses: Mapping[str, ArrayLike] | None = None,
    noise: MeasurementNoise = MeasurementNoise(),
    frame_period_s: float | None = None,
    lag_frames: Mapping[str, int] | None = None,
) -> JointCalibration:
    """Refine node poses jointly with the target's states (module doc).

    Parameters
    ----------
    detections : name -> Detections (or ``(frame (K,), measurements (K, 3))``)
        One detection of the common target per node per frame, frames
        already corrected for each node's whole-frame lag (``lag_frames``).
        The first node is the reference unless ``reference`` names another.
    options : how to solve (:class:`JointOptions`; None: its defaults).
    initial_poses : name -> (3,), optional
        Starting poses (the reference's is ignored); by default the trimmed
        closed form (and a pose graph for N > 2).
    noise : measurement noise of the detections (default: the paper's).
    frame_period_s : the frame period (s); needed by the motion factors,
        the clock offsets and ``lag_frames``.
    lag_frames : name -> the whole-frame lag already removed from the node's
        frames (its frame ``k + lag`` is the reference's ``k``, as in
        :class:`~mmsnap_graph.data.calibration.RecordingCalibration`): the offset
        starts at ``-lag * frame_period_s``, part of ``time_offset_s``.

    Returns
    -------
    JointCalibration
    """
    options = JointOptions() if options is None else options
    inputs = _inputs(detections, reference, initial_poses, noise, frame_period_s, lag_frames,
                     options)
    result = _calibrate_once(inputs, options)
    if (options.time_offsets and options.recentre_lags and inputs.frame_period_s is not None
            and result.success):
        result = _recentred_lags(result, inputs, options)
    return result


def _calibrate_once(inputs: _Inputs, options: JointOptions) -> JointCalibration:
    """One joint calibration with the whole-frame lags as given."""
    frames, init, x0, unreachable, graph = _setup(inputs, options)
    try:
        result = _estimate(graph, frames, init, x0, unreachable, inputs.sigmas, options)
    except MmsnapError:
        raise
    except _NUMERICAL_ERRORS as exc:
        result = _broken_down(graph, frames, init, x0, unreachable, exc)
    return dataclasses.replace(result, lag_frames={n: inputs.lag_frames.get(n, 0)
                                                   for n in graph.active})


#: A node whose estimated clock offset lies more than this fraction of a frame
#: beyond its whole-frame lag is solved again with the lag moved one frame
#: toward it (module doc, "Clock offsets").
LAG_RECENTRE_FRACTION = 0.25


def _recentred_lags(result: JointCalibration, inputs: _Inputs,
                    options: JointOptions) -> JointCalibration:
    """``result``, or the solve with every node whose offset fraction exceeds
    :data:`LAG_RECENTRE_FRACTION` moved to the neighbouring whole-frame lag,
    whichever has the lower final error. The offset enters the model to
    first order (``F(tau) x``): a lag one frame off (e.g. from EKF tracks,
    whose filter delays differ from node to node) is only partly recovered,
    and the poses absorb the rest (docs/CALIBRATION.md, "What
    ``calibrate_recording`` reports")."""
    period = inputs.frame_period_s
    lags = dict(inputs.lag_frames)
    moves = {}
    for n, offset in result.time_offset_s.items():
        frac = (offset + lags.get(n, 0) * period) / period
        if n != result.reference and abs(frac) > LAG_RECENTRE_FRACTION:
            moves[n] = int(np.sign(frac))
    if not moves:
        return result
    dets = {n: ((fr + moves.get(n, 0)), z) for n, (fr, z) in inputs.detections.items()}
    new_lags = {**lags, **{n: lags.get(n, 0) - d for n, d in moves.items()}}
    again = _calibrate_once(dataclasses.replace(inputs, detections=dets, lag_frames=new_lags,
                                                initial_poses=result.poses), options)
    better = again.success and again.final_error < result.final_error
    return again if better else result


def _setup(inputs: _Inputs, options: JointOptions):
    """Frames, starting poses and states, and the graph (the part of
    :func:`joint_calibration` after validation)."""
    dets, ref, sig = inputs.detections, inputs.reference, inputs.sigmas
    names = list(dets)
    prior_sig = np.asarray(options.state_prior_sigmas)
    frames, meas_f = _frame_table(dets, names, options.min_common_frames)
    init, unreachable = _start_poses(meas_f, names, ref, inputs.initial_poses,
                                     options.min_common_frames, options.min_spread_m)
    active = [n for n in names if n not in unreachable]
    frames, meas_f = _restrict(frames, meas_f, active, options.min_common_frames)
    x0 = starting_states(meas_f, init, active, sig, prior_sig[2])
    motion = motion_spec(frames, options.motion, inputs.frame_period_s,
                         options.max_motion_gap_frames, options.sigma_a_mps2,
                         options.motion_robust if options.robust else None,
                         options.motion_robust_k)
    graph = JointGraph(meas_f, active, ref, prior_sig, motion,
                       timed=active if options.time_offsets else ())
    period = float(inputs.frame_period_s or 0.0)
    graph.lag_offsets = {n: -inputs.lag_frames.get(n, 0) * period for n in active}
    graph.frame_period_s = inputs.frame_period_s
    return frames, init, x0, unreachable, graph


def _estimate(graph, frames, init, x0, unreachable, sig,
              options: JointOptions) -> JointCalibration:
    """Solve, assess, and the result (the numerical part of
    :func:`joint_calibration`)."""
    active, ref = graph.active, graph.ref
    final_graph, result, run = _solve(graph, {n: init[n] for n in active}, x0, sig, options)
    poses, states, offsets = graph.current(result)
    covs, variances, state_covs, unobservable, schur_failure, joint_cov = assess(
        graph, final_graph, result, options.state_covariances, options.max_pose_variance,
        options.max_pose_condition, run["linear"])
    block, covariance = None, PoseCovariance(method="marginals")
    if schur_failure:
        covariance = PoseCovariance(method="schur", failure=schur_failure)
    elif not unobservable and joint_cov is not None:
        block = _block_covariance(graph, (poses, states, offsets), sig, options, run, frames)
        if isinstance(block, str):
            covariance, block = PoseCovariance(method="marginals", failure=block), None
    if block is not None:
        covs, variances, joint_cov = _from_block(block, graph, covs, variances)
        covariance = block.fact()
    steps = graph.presolve_steps
    facts: list[CalibrationFact] = [JointFit(
        n_nodes=len(active), n_frames=frames.size,
        n_outliers=sum(int(o.sum()) for o in run["outliers"].values()),
        iterations=run["iterations"], presolve_steps=tuple(n for n, _ in steps),
        presolve_converged=all(c for _, c in steps), turns=run["turns"]), covariance]
    if options.range_offset_prior_m is not None:
        facts.append(RangeOffsetEstimated(
            offset_m=graph.range_offset_m,
            variance_m2=block.variance(("range",)) if block is not None else float("nan"),
            prior_mean_m=options.range_offset_prior_m[0],
            prior_sigma_m=options.range_offset_prior_m[1]))
    facts += [PoseNotObservable(node=n, directions=tuple(map(tuple, dirs)))
              for n, dirs in unobservable.items()]
    status = (CalibrationStatus.NODES_UNREACHABLE if unreachable else
              CalibrationStatus.NOT_OBSERVABLE if unobservable else CalibrationStatus.OK)
    return JointCalibration(
        reference=ref, poses=poses, covariances=covs,
        initial_poses={n: np.asarray(init[n], dtype=float) for n in active}, frames=frames,
        states=states, state_covariances=state_covs, outliers=run["outliers"],
        status=status, facts=tuple(facts), iterations=run["iterations"],
        initial_error=run["initial_error"], final_error=run["final_error"],
        unobservable=unobservable, unreachable=tuple(unreachable),
        time_offset_s={n: graph.lag_offsets[n] + offsets[n] for n in active},
        time_offset_variances=variances, turns=run["turns"], joint_covariance=joint_cov,
        joint_order=tuple(n for n in active if n != ref) if joint_cov is not None else (),
        range_offset_m=(graph.range_offset_m if options.range_offset_prior_m is not None
                        else float("nan")),
        range_offset_variance=(block.variance(("range",)) if block is not None
                               else float("nan")),
        model_covariances=(_from_block(dataclasses.replace(block, covariance=block.model),
                                       graph, covs, variances)[0] if block is not None
                           else dict(covs)),
        pose_block=block)


def _block_covariance(graph, point, sig, options: JointOptions, run, frames):
    """The pose block's covariance (:mod:`.covariance`) of the final
    Gaussian pass, None when the options ask for the graph's marginals, or
    why the long-run covariance failed (the marginals are kept)."""
    long_run = options.covariance == "long_run" and graph.frame_period_s is not None
    if options.range_offset_prior_m is None and not long_run:
        return None
    poses, states, offsets = point
    problem = _problem(graph, sig, options, kernel=False, motion=run["motion"], use=run["use"])
    given = {n: offsets[n] for n in graph.timed}
    if problem.range_offset is not None:
        given[RANGE_OFFSET] = 0.0
    bandwidth = (bandwidth_frames(options.covariance_bandwidth_s, graph.frame_period_s)
                 if long_run else None)
    try:
        return block_covariance(problem, poses, states, given or None, frames,
                                bandwidth=bandwidth, timed=graph.timed,
                                range_offset_rms=options.range_offset_rms_m)
    except (np.linalg.LinAlgError, ValueError) as exc:
        return f"the long-run covariance failed: {exc}"


def _from_block(block: BlockCovariance, graph, covs, variances):
    """Marginals, offset variances and the joint pose covariance from a
    :class:`BlockCovariance`."""
    others = [n for n in graph.active if n != graph.ref]
    covs = {**covs, **{n: block.node(n) for n in others}}
    variances = {**variances, **{n: block.variance(("offset", n)) for n in graph.timed}}
    p = 3 * len(others)
    return covs, variances, block.covariance[:p, :p].copy()


def _broken_down(graph, frames, init, x0, unreachable, exc) -> JointCalibration:
    """The result when the estimation broke down: the starting poses and
    states, NaN covariances, ``SOLVE_FAILED`` and the reason."""
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
        outliers={n: np.zeros(graph.f, dtype=bool) for n in active},
        status=CalibrationStatus.SOLVE_FAILED,
        facts=(SolveBrokeDown(step="joint", reason=reason),),
        iterations=0, initial_error=float("nan"), final_error=float("nan"), unobservable={},
        unreachable=tuple(unreachable), time_offset_s=dict(graph.lag_offsets),
        time_offset_variances={n: (0.0 if n == ref else float("nan")) for n in active})
