"""Calibrate every node of a recording.

:func:`calibrate_recording` chains the steps: each node's local tracks (EKF
tracks when the recording has them, else centroids mapped to local xy),
track matching and lag search for every node pair, the pose graph anchored
at the reference (first) node, and the joint calibration graph on the raw
centroid measurements, started from the pose graph: directly when every
calibrated node has one centroid per frame, else (several people, clutter,
sparse clouds) after associating the centroids across nodes, in rounds of
association and joint solve
(:func:`~mmsnap_graph.calibration.joint.multi_refine.refine_associated`). The result, a
:class:`~mmsnap_graph.data.calibration.RecordingCalibration` with a status
and the typed facts each step found (:mod:`mmsnap_graph.data.calibration_facts`),
is stored and read back by :mod:`mmsnap_graph.io.calibration` (the
``/calibration`` group and the calibration JSON).

The centroid noise comes from the data first
(:mod:`mmsnap_graph.calibration.noise.estimate`): the one-centroid joint graph
is weighted by each node's temporal estimate (no poses needed), the
multi-target one by the noise learned from its residuals; once the poses are
known every node's noise is estimated again from the cross-node residuals
and the temporal differences together (``RecordingCalibration.noise``,
stored as ``/noise`` by ``mmsnap calibrate``). A simulator's metadata sigmas
are not used: a recording's data are what a user has.

The joint graph's default options follow what the recording says its radars
see (``Recording.targets``, :data:`JOINT_OPTIONS_BY_TARGETS`).
"""

from __future__ import annotations

import dataclasses
from typing import Literal, Mapping

import numpy as np

from ..errors import CalibrationError, MissingStepError, ValidationError
from ..data.calibration import RecordingCalibration
from ..data.calibration_facts import (
    NOISE_COMPONENTS,
    CalibrationFact,
    CalibrationStatus,
    JointNoise,
    JointRejected,
    JointSkipped,
    LagNotDetermined,
    LagsDisputed,
    NoiseNotIdentified,
    TargetsAssociated,
)
from ..data.noise import MeasurementNoise, NodeNoiseEstimate, NoiseEstimate
from ..data.recording import Detections, NodeData, Recording
from .joint.options import REFLECTION_DEPTH_RMS_M, JointOptions
from .joint.solve import joint_calibration
from .pairwise.matching import LocalTracks, local_tracks
from .pairwise.matching_options import MatchingOptions
from .joint.multi_refine import refine_associated, with_clock_offsets
from .joint.multi_target import joint_detections_multi
from .noise.estimate import estimate_noise
from .lag_support import unrejected_lag_spread
from .pairwise.matching import LAG_EVIDENCE_Z
from .pairwise.pose_graph import pairwise_edges, pose_graph_calibration

__all__ = ["POINT_JOINT_OPTIONS", "PEOPLE_JOINT_OPTIONS", "JOINT_OPTIONS_BY_TARGETS",
           "joint_options_for", "calibrate_recording", "noise_at_poses"]

#: The joint graph's options for point targets (``Recording.targets =
#: "points"``, the simulator's clean model): constant-velocity factors (they
#: let a ghost stand out from the smooth track; without them a free per-frame
#: state absorbs part of it) with a white-acceleration sigma that covers a
#: walking person's accelerations (a tighter sigma biased the poses:
#: docs/CALIBRATION.md, "Limits"), and each node's clock offset.
POINT_JOINT_OPTIONS = JointOptions(motion=True, sigma_a_mps2=3.0, time_offsets=True)
#: The same for recordings of people (``Recording.targets = "people"``, real
#: radars): their reflection depth, not estimated, considered in the pose
#: covariance (``JointOptions.range_offset_rms_m``; docs/CALIBRATION.md).
PEOPLE_JOINT_OPTIONS = dataclasses.replace(POINT_JOINT_OPTIONS,
                                           range_offset_rms_m=REFLECTION_DEPTH_RMS_M)
#: ``Recording.targets`` -> the joint graph's default options. Point targets
#: leave the reflection depth's term out: every radar sees the whole target,
#: so its centroids carry no depth and the term would only widen the
#: covariance (the fused NEES fell below its band with it: docs/validation/calibration.md, "Figures behind the estimators' rules").
JOINT_OPTIONS_BY_TARGETS = {"people": PEOPLE_JOINT_OPTIONS, "points": POINT_JOINT_OPTIONS}


def joint_options_for(recording: Recording) -> JointOptions:
    """The joint graph's default options for ``recording``: by the target
    model it declares (:data:`JOINT_OPTIONS_BY_TARGETS`)."""
    return JOINT_OPTIONS_BY_TARGETS[recording.targets]


def _joint_detections(rec: Recording, names, lags) -> dict[str, Detections] | None:
    """Each node's centroids on the reference's frame clock, or None when a
    node has no centroids or several per frame (the joint graph needs one
    detection of the common target per node per frame)."""
    out = {}
    for n in names:
        det = rec.nodes[n].centroids
        if det is None or len(det) == 0 or np.unique(det.frame).size != det.frame.size:
            return None
        out[n] = dataclasses.replace(det, frame=det.frame - int(lags.get(n, 0)))
    return out


def _first_noise(pg: RecordingCalibration, dets: Mapping[str, Detections]) -> MeasurementNoise:
    """First guess of the centroid noise: the cross-range noise the closed
    form's track RMSE implies (RMSE^2 ~ two nodes' cross-range variances) as
    omega = pi x / r; the paper's range and Doppler sigmas."""
    paper = MeasurementNoise()
    rmse = float(np.median([e.rmse_m for e in pg.edges]))
    mean_range = float(np.mean(np.concatenate([d.range_m for d in dets.values()])))
    omega0 = float(np.clip(np.pi * rmse / (np.sqrt(2.0) * mean_range), 0.01, paper.omega_rad))
    return dataclasses.replace(paper, omega_rad=omega0)


def _joint_noise(recording, pg, dets) -> tuple[MeasurementNoise, JointNoise]:
    """The joint graph's noise before the poses are refined: the nodes'
    temporal estimates pooled (each node's own centroid sequence, no poses
    needed); a component none identifies takes the closed form's track RMSE
    (spatial frequency) or the paper's value."""
    first = _first_noise(pg, dets)
    est = estimate_noise(recording, lag_frames=pg.lag_frames, method="temporal", fallback=first)
    noise = est.pooled()
    identified = tuple(any(e.identified[i] for e in est.nodes.values()) for i in range(3))
    return noise, JointNoise(sigmas=noise.sigmas, identified=identified, source="temporal")


def _refine(recording, pg, reachable, method, noise, options: JointOptions, facts):
    """The joint step: its result (None when skipped) and, with several
    centroids per frame, the associated detections it ran on and the clock
    offsets of the solve with time offsets (else None, None); what it found
    is added to ``facts``."""
    dets = _joint_detections(recording, reachable, pg.lag_frames)
    if dets is None:
        out = _refine_multi(recording, pg, reachable, method, noise, options, facts)
        return (None, None, None) if out is None else (out.joint, out.detections,
                                                       out.clock_offsets)
    if noise is None:
        noise, said = _joint_noise(recording, pg, dets)
    else:
        said = JointNoise(sigmas=noise.sigmas, identified=(True,) * 3, source="given")
    facts.append(said)
    joint = joint_calibration(dets, options, noise=noise,
                              initial_poses={n: pg.poses[n] for n in reachable},
                              frame_period_s=recording.frame_period_s,
                              lag_frames={n: int(pg.lag_frames.get(n, 0)) for n in reachable})
    facts.extend(joint.facts)
    return joint, None, None


def _refine_multi(recording, pg, reachable, method, noise, options, facts):
    """Several centroids per frame (several people, clutter, sparse clouds):
    associate them across nodes with the calibration in progress, rounds of
    association and joint solve (:func:`~mmsnap_graph.calibration.joint.multi_refine.refine_associated`),
    the noise learned from the joint graph's residuals unless given.

    The rounds solve in whole-frame lags; the clock offsets beyond them
    (``options.time_offsets``) come from one more solve on the associated
    centroids, kept only when the data support them
    (:func:`~mmsnap_graph.calibration.joint.multi_refine.with_clock_offsets`):
    estimated in the rounds, they came out several of their sigmas from a
    true zero and moved the poses (docs/CALIBRATION.md, "Several people")."""
    try:
        out = refine_associated(recording, reachable, pg.poses, pg.covariances, pg.lag_frames,
                                noise=noise,
                                options=dataclasses.replace(options, time_offsets=False))
    except CalibrationError as exc:  # e.g. no centroids at all (tracks only)
        out, why = None, str(exc)
    else:
        why = ""
    if out is None:
        if method == "joint":
            raise CalibrationError("the joint calibration needs centroids of a common target "
                                   "from at least two nodes; none could be associated"
                                   + (f" ({why})" if why else ""))
        facts.append(JointSkipped(association_error=why))
        return None
    facts.append(TargetsAssociated(n_targets=out.association.n_targets,
                                   n_states=out.association.n_groups))
    facts.append(JointNoise(sigmas=out.noise.sigmas, identified=(True,) * 3,
                            source="residuals" if noise is None else "given"))
    if options.time_offsets:
        out, tried = with_clock_offsets(out, recording, options)
        facts.append(tried)
    facts.extend(out.joint.facts)
    return out


def _pose_graph_step(recording, names, source, matching: MatchingOptions):
    """Local tracks of every node, pairwise matches, the pose graph."""
    ref = names[0]
    tracks: dict[str, LocalTracks] = {}
    failures: dict[str, str] = {}
    steps: dict[str, str] = {}
    for n in names:
        try:
            tracks[n] = local_tracks(recording.nodes[n], source)
        except CalibrationError as exc:
            failures[n] = str(exc)
            if isinstance(exc, MissingStepError):
                steps[n] = exc
    if ref not in tracks:
        text = f"reference node {ref}: {failures[ref]}"
        if ref in steps:
            raise MissingStepError(text, step=steps[ref].step,
                                   what=f"reference node {ref}: {steps[ref].what}")
        raise CalibrationError(text)
    edges, pair_fail = pairwise_edges(tracks, frame_period_s=recording.frame_period_s,
                                      options=matching)
    failures.update(pair_fail)
    if not edges:
        raise CalibrationError(
            f"no pair of nodes shares a matched track (matching: {matching.describe()}): "
            + "; ".join(f"{k}: {v}" for k, v in failures.items()))
    return pose_graph_calibration(names, edges, failures=failures), tracks[ref].source, failures


def calibrate_recording(
    recording: Recording,
    *,
    source: Literal["auto", "tracks", "centroids"] = "auto",
    method: Literal["auto", "joint", "pose_graph"] = "auto",
    noise: MeasurementNoise | None = None,
    matching: MatchingOptions | None = None,
    joint: JointOptions | None = None,
) -> RecordingCalibration:
    """Calibrate every node of ``recording``: each node's pose in the first
    node's (the reference's) frame, with its covariance, frame lag and clock
    offset (module doc).

    What must exist first: at least two nodes, each with EKF tracks (``mmsnap
    process`` makes them from centroids or point clouds) or centroids (one
    per frame, or labelled with ``target_id`` when several people walk), and
    a target that both nodes of a pair see moving for ``matching.min_common_s``
    seconds. Poses stored on the nodes are not used (they are what this
    estimates).

    Returns a :class:`~mmsnap_graph.data.calibration.RecordingCalibration`:
    ``poses`` and ``covariances`` (Pose2 body tangent, ``(x_m, y_m,
    phi_rad)``) of every calibrated node, their ``joint_covariance``,
    ``lag_frames`` and ``time_offset_s`` per node, ``unreachable`` nodes, the
    pairwise ``edges``, ``method`` (``"joint"`` or ``"pose_graph"``),
    ``source``, ``status`` (why it is not usable, or ``OK``), ``facts``
    (what each step found or could not determine: lags, noise, covariance
    method, ...), ``failures`` (nodes and pairs that could not be used) and
    ``noise`` (every node's sigmas from the data).
    :func:`mmsnap_graph.io.calibration.write_calibration` stores it as the
    recording's ``/calibration`` group (``mmsnap calibrate``).

    source : the local positions to match: EKF tracks when present
        (``"auto"``), ``"tracks"`` or ``"centroids"``.
    method : ``"pose_graph"`` stops after the pose graph of pairwise closed
        forms; ``"joint"`` requires the joint refinement (CalibrationError if
        the centroids cannot feed it); ``"auto"`` refines when it can.
    noise : measurement noise of the centroids for the joint graph;
        None (default): estimated from the data, each node's own centroid
        sequence pooled over the nodes (module doc); the recording's
        metadata sigmas are not used. Wrong sigmas cost accuracy: the
        joint graph weighs range against spatial frequency by them.
        The result's ``noise``: every node's estimate at the calibrated
        poses (from the associated centroids with several per frame).
    matching : the track matching's thresholds in seconds and metres
        (:class:`MatchingOptions`; None: its defaults): lags up to
        ``max_lag_s`` (whole frames of the recording's period) are searched,
        a track pair must share ``min_common_s`` of a target that moves
        ``min_spread_m`` in each node, a match whose track RMSE exceeds
        ``max_rmse_m`` is rejected. Lags that the joint graph's clock
        offsets dispute give way to lag 0 (:func:`_disputed_lags`: the
        calibration is made once more with lag 0 only, and says so).
    joint : the joint graph's options (None: :func:`joint_options_for` the
        recording, by its declared target model). Clock offsets
        (``time_offsets``, a fraction of a frame beyond the whole-frame lag
        of the track matching; docs/CALIBRATION.md, "Clock offsets") need
        the motion factors; with several centroids per frame they are kept
        only when the data support them (:func:`_refine_multi`).
    Raises :class:`CalibrationError` when no node pair can be matched.
    """
    return calibrate_with_joint(recording, source=source, method=method, noise=noise,
                                matching=matching, joint=joint)[0]


def calibrate_with_joint(recording: Recording, *, source="auto", method="auto", noise=None,
                         matching=None, joint=None, noise_estimate: bool = True):
    """:func:`calibrate_recording` (same arguments) and the
    :class:`~mmsnap_graph.calibration.joint.solve.JointCalibration` its
    poses come from (None when they are the pose graph's): its
    ``pose_block`` is what a windowed calibration combines
    (:mod:`mmsnap_graph.calibration.joint.windowed`). ``noise_estimate``
    False: no noise estimate at the calibrated poses (``noise`` None; the
    windows after the first skip it, half of a window's time at 10 nodes)."""
    matching = _checked_options(method, noise, matching, joint)
    names = _checked_nodes(recording)
    joint = joint_options_for(recording) if joint is None else joint
    kept: list = []
    outcome = _calibrate(recording, names, source, method, noise, matching, joint, kept,
                         noise_estimate)
    if not isinstance(outcome, LagsDisputed):
        return outcome, (kept[-1] if kept else None)
    # Once more with lag 0 only (the nodes' own sync): no lag is left to dispute.
    kept.clear()
    again = _calibrate(recording, names, source, method, noise,
                       dataclasses.replace(matching, max_lag_s=0.0), joint, kept,
                       noise_estimate)
    return (dataclasses.replace(again, facts=(outcome, *again.facts)),
            kept[-1] if kept else None)


def _calibrate(recording, names, source, method, noise, matching: MatchingOptions,
               joint: JointOptions, kept: list,
               noise_estimate: bool = True) -> RecordingCalibration | LagsDisputed:
    """One pass of :func:`calibrate_recording` with these lag rules: the
    calibration, or the joint graph's dispute of the track matching's lags
    (the pass then stops: the lags are searched again); the joint graph's
    result, when the poses are its, is appended to ``kept``."""
    pg, used_source, failures = _pose_graph_step(recording, names, source, matching)
    facts: list[CalibrationFact] = list(pg.facts)
    poses, covs = dict(pg.poses), dict(pg.covariances)
    result_method, refined, associated, clock = "pose_graph", None, None, None
    reachable = [n for n in names if n in poses]
    if method in ("auto", "joint") and len(reachable) >= 2:
        options = dataclasses.replace(joint, time_offsets=joint.time_offsets and joint.motion)
        refined, associated, clock = _refine(recording, pg, reachable, method, noise, options,
                                             facts)
        disputed = _disputed_lags(pg.lag_frames, clock)
        if disputed is not None:
            return disputed
        if refined is not None and (refined.success or method == "joint"):
            poses = {n: refined.poses[n] for n in reachable}
            covs = {n: refined.covariances[n] for n in reachable}
            result_method = "joint"
        elif refined is not None:
            facts.append(JointRejected(status=refined.status))
            associated = None
    used = None if result_method != "joint" else (  # the centroids the joint graph fitted
        associated if associated is not None else _joint_detections(recording, reachable,
                                                                     pg.lag_frames))
    facts += [e.lag_evidence for e in pg.edges if e.lag_evidence is not None]
    widened = _cover_ambiguous_lags(pg.edges, covs, facts, used, clock, matching,
                                    recording.frame_period_s)
    status = pg.status
    if status is CalibrationStatus.OK and result_method == "joint":
        status = refined.status
    lags = dict(pg.lag_frames)
    if result_method == "joint":  # the joint graph may re-centre a whole-frame lag
        lags.update({n: int(v) for n, v in refined.lag_frames.items() if n in lags})
    noise_est = noise_at_poses(recording, poses, lags) if noise_estimate else None
    facts += _unidentified(noise_est) if noise_est is not None else []
    offsets, variances = _clock_offsets(recording, names, pg, refined if result_method == "joint"
                                        else None)
    step = refined if result_method == "joint" else pg
    if result_method == "joint":
        kept.append(refined)
    return RecordingCalibration(
        reference=names[0], node_names=tuple(names), poses=poses, covariances=widened,
        lag_frames=lags, unreachable=pg.unreachable, edges=pg.edges,
        method=result_method, source=used_source, status=status, facts=tuple(facts),
        failures=failures, noise=noise_est, time_offset_s=offsets,
        time_offset_variances=variances,
        range_offset_m=refined.range_offset_m if result_method == "joint" else float("nan"),
        range_offset_variance=(refined.range_offset_variance if result_method == "joint"
                               else float("nan")),
        joint_covariance=_widened_joint(step.joint_covariance, step.joint_order, covs, widened),
        joint_order=step.joint_order if step.joint_covariance is not None else (),
        model_covariances={n: step.model_covariances[n] for n in poses
                           if n in step.model_covariances})


def _widened_joint(joint_cov, order, before, after):
    """The joint pose covariance with each node's widening (``after -
    before``, the lag cover of :func:`_cover_ambiguous_lags`) added to its
    diagonal block; None stays None."""
    if joint_cov is None:
        return None
    out = np.array(joint_cov, dtype=float)
    for i, n in enumerate(order):
        if n in before and n in after:
            out[3 * i:3 * i + 3, 3 * i:3 * i + 3] += after[n] - before[n]
    return out


def _unidentified(noise: NoiseEstimate) -> list[NoiseNotIdentified]:
    """A fact for every node's noise component the data do not identify."""
    return [NoiseNotIdentified(node=n, component=comp, sigma=e.noise.sigmas[i],
                               reason=e.reasons[i])
            for n, e in noise.nodes.items() for i, comp in enumerate(NOISE_COMPONENTS)
            if not e.identified[i]]


def _checked_nodes(recording: Recording) -> list[str]:
    """The node names: at least two, none a copy of another."""
    names = list(recording.node_names)
    if len(names) < 2:
        raise CalibrationError(f"a calibration needs at least two nodes, got {names!r}")
    _no_identical_nodes(recording, names)
    return names


def _checked_options(method, noise, matching, joint) -> MatchingOptions:
    """The arguments of :func:`calibrate_recording` validated; the matching
    options (None: the defaults)."""
    if method not in ("auto", "joint", "pose_graph"):
        raise ValidationError(f"method={method!r} must be 'auto', 'joint' or 'pose_graph'")
    if noise is not None and not isinstance(noise, MeasurementNoise):
        raise ValidationError(f"noise must be a MeasurementNoise or None, got {noise!r}")
    matching = MatchingOptions() if matching is None else matching
    if not isinstance(matching, MatchingOptions):
        raise ValidationError(f"matching must be a MatchingOptions or None, got {matching!r}")
    if joint is not None and not isinstance(joint, JointOptions):
        raise ValidationError(f"joint must be a JointOptions or None, got {joint!r}")
    return matching


def _disputed_lags(lags, clock) -> LagsDisputed | None:
    """Why the whole-frame lags of the track matching are not determined,
    or None when they are: every nonzero lag's node has a clock offset from
    the joint graph's solve with time offsets (``clock``: node ->
    (fraction, sigma) in frames beyond the lag) more than half a frame and
    :data:`LAG_EVIDENCE_Z` sigmas from it. The tracks then prefer a lag
    that the centroids the joint graph associated do not (two walkers at
    right angles, synchronised, the heading a turn of a frame's shift off:
    docs/validation/calibration.md, "Figures behind the estimators' rules")."""
    lagged = {n: int(v) for n, v in lags.items() if int(v) != 0}
    if not lagged or clock is None:
        return None
    off = {n: clock.get(n, (0.0, float("nan"))) for n in lagged}
    if not all(abs(f) > 0.5 and abs(f) >= LAG_EVIDENCE_Z * sd for f, sd in off.values()):
        return None
    return LagsDisputed(nodes=tuple(off), lags=tuple(lagged[n] for n in off),
                        fractions=tuple(f for f, _ in off.values()),
                        sigmas=tuple(sd for _, sd in off.values()), evidence_z=LAG_EVIDENCE_Z)


def _cover_ambiguous_lags(edges, covs, facts, used, clock, matching, period) -> dict:
    """The covariances of the nodes of an ambiguous-lag edge widened to
    cover the poses of the lags the final model cannot reject (a
    :class:`~mmsnap_graph.data.calibration_facts.LagNotDetermined` added to
    ``facts`` for each): the refinement fits one lag and its covariance is
    that lag's alone (a walk along a circle: 0.8 m off with a 0.08 m sigma).

    With the centroids the joint graph was fitted on (``used``, node ->
    detections on the reference clock), each shift within the matching's
    window (frames at ``period``) is tested on them with the matching's
    inlier gate (:func:`~mmsnap_graph.calibration.lag_support.unrejected_lag_spread`),
    and against the joint graph's clock offset (``clock``: node ->
    (fraction, sigma) in frames, from the solve with time offsets, kept or
    not): a shift ``LAG_EVIDENCE_Z`` of its sigmas from the offset is
    rejected. Node b's covariance grows by the spread of the shifts that
    neither rejects: the track matching's own spread covers fits of other
    track pairs and of smoothed tracks, many times the errors
    (docs/validation/calibration.md, "Figures behind the estimators' rules"). Without them (the pose graph's
    result) the edge's widened covariance is a PSD lower bound of both
    nodes'."""
    out = dict(covs)
    for e in edges:
        if not e.lag_ambiguous:
            continue
        a, b = e.node_a, e.node_b
        if used is not None and a in used and b in used and b in out and np.any(out[b]):
            window = matching.frame_counts(period)[0]
            shifts = [k for k in range(-window, window + 1) if k]
            # A shift of k frames (node b's frame k + L paired with a's k) is
            # a clock offset of -k frames beyond the lag L.
            frac, sd = (clock or {}).get(b, (0.0, float("nan")))
            timed_out = [k for k in shifts if abs(k + frac) >= LAG_EVIDENCE_Z * sd]
            extra, kept, rejected = unrejected_lag_spread(
                used[a], used[b], [k for k in shifts if k not in timed_out],
                matching.inlier_gate_m, out[b])
            rejected = sorted(rejected + timed_out)
            out[b] = out[b] + extra
            facts.append(LagNotDetermined(node_a=a, node_b=b, tested=True,
                                          kept_shifts=tuple(kept), rejected_shifts=tuple(rejected),
                                          clock_fraction=frac, clock_sigma=sd,
                                          evidence_z=LAG_EVIDENCE_Z))
            continue
        facts.append(LagNotDetermined(node_a=a, node_b=b, tested=False))
        for n in (e.node_a, e.node_b):
            if n in out and np.any(out[n]):
                gap_val, gap_vec = np.linalg.eigh(e.covariance - out[n])
                out[n] = out[n] + (gap_vec * np.maximum(gap_val, 0.0)) @ gap_vec.T
    return out


def _several_per_frame(recording: Recording, names) -> bool:
    """Whether a node of ``names`` has frames with several centroids (two
    people, clutter, a split body)."""
    for n in names:
        det = recording.nodes[n].centroids
        if det is not None and len(det) and np.unique(det.frame).size != det.frame.size:
            return True
    return False


def noise_at_poses(recording: Recording, poses: Mapping[str, np.ndarray],
                   lag_frames: Mapping[str, int] | None = None, *,
                   method: Literal["auto", "network", "temporal"] = "auto") -> NoiseEstimate:
    """Every node's noise at the node ``poses`` (frame ``lag_frames``): the
    one estimate of ``mmsnap calibrate`` (at the poses it calibrated) and
    ``mmsnap noise`` (at the stored poses or a calibration JSON's).

    Where each node has one centroid per frame, from its centroids
    (:func:`~mmsnap_graph.calibration.noise.estimate.estimate_noise`). With
    several per frame (two people, clutter, split clusters) the single-centroid
    frames of two nodes may be of two people (on the two-person recording
    S2's range sigma came out 1.486 m from them, against 0.094 m from one
    target): the centroids are then associated across nodes first, one per
    node and virtual frame, their cross-node residuals of one target by
    construction
    (:func:`~mmsnap_graph.calibration.joint.multi_target.joint_detections_multi`
    at ``poses`` with the gates' floor only: the poses are taken as known;
    a calibration's widened covariances open the gates to the other person,
    S2's range sigma 0.83 m). ``mmsnap calibrate`` associates once more at
    the poses it found rather than reusing its last round's association
    (made at the round's starting poses with its covariances): the two
    verbs then give the same sigmas on the same poses (they differed by up
    to 13 % on the fall-detection recording). Per node and component the associated estimate
    when it is identified, else the recording's when that is
    (:func:`_merged_noise`).
    """
    lags = {} if lag_frames is None else dict(lag_frames)
    own = estimate_noise(recording, poses=poses, lag_frames=lags, method=method)
    posed = [n for n in recording.node_names if n in poses]
    associated = None
    if len(posed) >= 2 and _several_per_frame(recording, posed):
        try:
            associated, _, _ = joint_detections_multi(recording, posed, poses, lags)
        except CalibrationError:
            associated = None
    if associated is None:
        return own
    nodes = {n: NodeData(name=n, centroids=associated.get(n)) for n in recording.node_names}
    assoc = estimate_noise(Recording(frame_period_s=recording.frame_period_s, nodes=nodes),
                           poses=poses, method=method)
    return _merged_noise(assoc, own)


def _merged_noise(assoc: NoiseEstimate, own: NoiseEstimate) -> NoiseEstimate:
    """Per node and component, ``assoc``'s sigma when identified, else
    ``own``'s when identified, else ``assoc``'s fallback."""
    nodes, n_id = {}, 0
    for name, a in assoc.nodes.items():
        o = own.nodes.get(name, a)
        pick = [a if a.identified[i] or not o.identified[i] else o for i in range(3)]
        sig = [pick[i].noise.sigmas[i] for i in range(3)]
        methods = sorted({("associated " if pick[i] is a else "own ") + pick[i].method
                          for i in range(3) if pick[i].identified[i]})
        nodes[name] = NodeNoiseEstimate(
            noise=MeasurementNoise(range_m=sig[0], omega_rad=sig[1], doppler_mps=sig[2]),
            identified=tuple(pick[i].identified[i] for i in range(3)),
            n_residuals=tuple(pick[i].n_residuals[i] for i in range(3)),
            method="; ".join(methods) or a.method,
            reasons=tuple(pick[i].reasons[i] for i in range(3)),
            tail_factors=tuple(pick[i].tail_factors[i] for i in range(3)))
        n_id += sum(nodes[name].identified)
    msg = (f"noise from the data ({assoc.method}): {n_id} of {3 * len(nodes)} node sigmas "
           f"identified (the centroids associated across nodes, else each node's own "
           f"single-centroid frames)")
    return NoiseEstimate(nodes=nodes, fallback=assoc.fallback, method=assoc.method, message=msg)


def _no_identical_nodes(recording: Recording, names: list[str]) -> None:
    """Two nodes with the same centroids in the same frames (one log imported
    twice) leave the relative pose singular: say so instead of failing in the
    solver."""
    seen: dict[tuple, str] = {}
    for name in names:
        c = recording.nodes[name].centroids
        if c is None or len(c.frame) < 2:
            continue
        key = (c.frame.tobytes(), c.range_m.tobytes(), c.omega_rad.tobytes(),
               c.doppler_mps.tobytes())
        if key in seen:
            raise CalibrationError(f"nodes {seen[key]} and {name} hold the same {len(c.frame)} "
                                   "centroids in the same frames: one log imported twice? "
                                   "(re-import with each node's own log)")
        seen[key] = name


def _clock_offsets(recording, names, pg, joint):
    """Each calibrated node's clock offset and its variance: the joint
    graph's when it ran, else the whole-frame lag's (variance NaN)."""
    period = recording.frame_period_s
    offsets, variances = {}, {}
    for n in names:
        if n == names[0]:
            offsets[n], variances[n] = 0.0, 0.0
        elif joint is not None and n in joint.time_offset_s:
            offsets[n] = float(joint.time_offset_s[n])
            variances[n] = float(joint.time_offset_variances.get(n, np.nan))
        elif n in pg.lag_frames:
            offsets[n], variances[n] = -int(pg.lag_frames[n]) * period, float("nan")
    return offsets, variances
