"""The joint calibration graph on several people from a pose-graph result:
:func:`refine_multi` associates the centroids with the
pose graph's poses (:func:`~mmsnap_graph.calibration.joint.multi_target.joint_detections_multi`),
picks the centroid noise as :func:`~mmsnap_graph.calibration.calibrate_recording`
does, and runs :func:`~mmsnap_graph.calibration.joint.solve.joint_calibration`
unchanged on the targets' blocks of virtual frames.

The association is only as good as the poses it starts from: on sparse
clouds (2-3 points per frame) the pose graph is often 0.1-0.5 m
off, the gates then miss or mix people, and one joint solve inherits that.
:func:`refine_associated` therefore alternates (``n_rounds``): associate
with the current poses, solve the joint graph, associate again with its
poses, covariances and the noise learned from its residuals, until the
poses stop moving (by less than :data:`ROUND_TOLERANCE`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Mapping

import numpy as np

from factors.models import detection_to_local

from ..._validation import check_count
from ...data.calibration import RecordingCalibration
from ...data.calibration_facts import ClockOffsetsTried, RobustPassFailed
from ...data.noise import MeasurementNoise, declared_noise
from ...data.recording import Recording
from ...errors import CalibrationError, ValidationError
from .options import JointOptions
from .solve import JointCalibration, joint_calibration
from .multi_target import (
    ASSOCIATION_NOISE,
    AssociationOptions,
    TargetAssociation,
    TargetMapping,
    joint_detections_multi,
)
from ..poses import pose_tangent_error
from .residual_noise import residual_noise

__all__ = ["MultiTargetRefinement", "refine_multi", "refine_associated", "with_clock_offsets",
           "DEFAULT_ROUNDS", "OFFSET_EVIDENCE_Z"]

#: Rounds of association and joint solve (module doc).
DEFAULT_ROUNDS = 3
#: The rounds stop when no pose moved by more than this (m, and rad).
ROUND_TOLERANCE = 1e-3
#: A node's clock offset beyond its whole-frame lag is kept when it lies
#: this many of its reported sigmas from zero (:func:`with_clock_offsets`).
OFFSET_EVIDENCE_Z = 3.0

#: Two centroids of one node in one frame closer than this (m) may be the
#: halves of one split body (the simulator's real model splits them 0.3-0.6
#: m apart); :func:`with_clock_offsets` leaves such frames of the node out.
SPLIT_RADIUS_M = 0.7

#: The joint graph's options of :func:`refine_multi` by default: as
#: :func:`~mmsnap_graph.calibration.calibrate_recording`'s, whole-frame lags
#: only.
MULTI_JOINT_OPTIONS = JointOptions(motion=True, sigma_a_mps2=3.0)


@dataclass(frozen=True, kw_only=True, slots=True)
class MultiTargetRefinement:
    """Result of :func:`refine_multi`: the joint graph's result (its frames
    are virtual frames), the mapping back to ``(frame, target)``, the
    association and the measurement noise used; detections: the
    associated detections the joint graph ran on (virtual frames);
    clock_offsets: per node the clock offset of the solve with time offsets
    (:func:`with_clock_offsets`, kept or not) as ``(fraction of a frame
    beyond the whole-frame lag, its sigma in frames)``, None when it did not
    run: which whole-frame lags the joint graph can reject."""

    joint: JointCalibration
    mapping: TargetMapping
    association: TargetAssociation
    noise: MeasurementNoise
    detections: Mapping | None = None
    clock_offsets: Mapping | None = None


def _learned_noise(dets, options: JointOptions, data: Mapping) -> MeasurementNoise:
    """The association noise, then the residuals of two joint solves without
    motion factors (:func:`residual_noise`); ``data``: the keyword data of
    :func:`joint_calibration`."""
    noise = ASSOCIATION_NOISE
    plain = dataclasses.replace(options, motion=False, time_offsets=False)
    for _ in range(2):
        first = joint_calibration(dets, plain, noise=noise, **data)
        if not first.success:
            break
        noise = residual_noise(first, dets, noise=noise)
    return noise


def _association_noise(noise: MeasurementNoise) -> MeasurementNoise:
    """The gates' noise after a round: the learned range and spatial
    frequency sigmas, never below :data:`ASSOCIATION_NOISE`'s."""
    return MeasurementNoise(range_m=max(noise.range_m, ASSOCIATION_NOISE.range_m),
                            omega_rad=max(noise.omega_rad, ASSOCIATION_NOISE.omega_rad),
                            doppler_mps=max(noise.doppler_mps, ASSOCIATION_NOISE.doppler_mps))


def _moved(joint: JointCalibration, poses: Mapping) -> float:
    """Largest change of a pose component between two rounds."""
    return max(float(np.max(np.abs(pose_tangent_error(joint.poses[n], poses[n]))))
               for n in joint.poses if n in poses)


def _one_round(recording, names, poses, covariances, lag_frames, noise,
               options: JointOptions, association):
    """Associate with ``poses`` and solve the joint graph: the refinement,
    or None when fewer than two nodes have associated centroids."""
    dets, mapping, assoc = joint_detections_multi(
        recording, names, poses, lag_frames, covariances=covariances,
        max_motion_gap_frames=options.max_motion_gap_frames, association=association)
    if dets is None:
        return None
    data = dict(reference=names[0], initial_poses={n: poses[n] for n in dets},
                frame_period_s=recording.frame_period_s,
                lag_frames={n: int(lag_frames.get(n, 0)) for n in dets})
    if noise is None:
        noise = _learned_noise(dets, options, data)
    joint = joint_calibration(dets, options, noise=noise, **data)
    if not joint.success and options.robust is not None:
        # The robust pass can leave GTSAM an indeterminate system (a dense
        # two-person scene: every detection of a state down-weighted);
        # the association has gated the outliers already: Gaussian factors.
        plain = joint_calibration(dets, dataclasses.replace(options, robust=None), noise=noise,
                                  **data)
        if plain.success:
            joint = dataclasses.replace(
                plain, facts=(*plain.facts, RobustPassFailed(status=joint.status)))
    return MultiTargetRefinement(joint=joint, mapping=mapping, association=assoc, noise=noise,
                                 detections=dets)


def refine_associated(recording: Recording, names, poses, covariances, lag_frames, *,
                      noise: MeasurementNoise | None, options: JointOptions,
                      association: AssociationOptions | None = None,
                      n_rounds: int = DEFAULT_ROUNDS) -> MultiTargetRefinement | None:
    """Rounds of association and joint solve (module doc) from ``poses``
    (``covariances`` may be None) of ``names`` (the first is the reference);
    ``options`` are the joint graph's (its ``max_motion_gap_frames`` also
    links the associated targets' states). ``noise`` None: learned from the
    residuals each round (the recording's metadata are not read). Returns
    the last successful round (else the first), None when the first
    association leaves fewer than two nodes."""
    if not isinstance(options, JointOptions):
        raise ValidationError(f"options must be a JointOptions, got {options!r}")
    check_count(n_rounds, "n_rounds")
    given = AssociationOptions() if association is None else association
    learn_gates = given.noise is None
    best = None
    for _ in range(int(n_rounds)):
        out = _one_round(recording, names, poses, covariances, lag_frames, noise, options,
                         given)
        if out is None or (best is not None and not out.joint.success):
            break
        moved = _moved(out.joint, poses)
        best = out
        if not out.joint.success or moved < ROUND_TOLERANCE:
            break
        poses = {**poses, **{n: out.joint.poses[n] for n in out.joint.poses}}
        # The association gates take the graph's own marginals: the long-run
        # widening covers errors that last seconds, not a frame's misfit.
        marg = out.joint.model_covariances or out.joint.covariances
        covariances = {n: marg[n] for n in out.joint.poses}
        if learn_gates:
            given = dataclasses.replace(given, noise=_association_noise(out.noise))
    return best


def refine_multi(
    recording: Recording,
    pose_graph: RecordingCalibration,
    options: JointOptions = MULTI_JOINT_OPTIONS,
    *,
    noise: MeasurementNoise | None = None,
    association: AssociationOptions | None = None,
    n_rounds: int = DEFAULT_ROUNDS,
) -> MultiTargetRefinement:
    """The joint calibration graph on several people, from the pose graph
    (module doc).

    pose_graph : a pose graph's
        :class:`~mmsnap_graph.data.calibration.RecordingCalibration` (e.g.
        ``calibrate_recording(rec, method="pose_graph")``): its poses,
        covariances and lags drive the first association and start the
        joint graph.
    noise : centroid noise of the joint graph; None: the noise the
        recording declares (:func:`~mmsnap_graph.data.noise.declared_noise`,
        a simulator's), else learned from the residuals as
        :func:`~mmsnap_graph.calibration.calibrate_recording` does (which
        never reads the declared noise).
    options : the joint graph's (:class:`JointOptions`; default
        :data:`MULTI_JOINT_OPTIONS`); clock offsets are not estimated here.
    association : the gates of :func:`associate_targets`
        (:class:`AssociationOptions`; its ``noise``, when given, is kept in
        every round).
    n_rounds : rounds of association and joint solve (module doc; 1: one
        association with the pose graph's poses).
    Raises :class:`CalibrationError` when fewer than two nodes have an
    associated centroid.
    """
    names = [pose_graph.reference] + [n for n in pose_graph.poses if n != pose_graph.reference]
    if not isinstance(options, JointOptions):
        raise ValidationError(f"options must be a JointOptions, got {options!r}")
    options = dataclasses.replace(options, time_offsets=False)
    if noise is None:
        noise = declared_noise(recording.metadata)
    out = refine_associated(recording, names, pose_graph.poses, pose_graph.covariances,
                            pose_graph.lag_frames, noise=noise, options=options,
                            association=association, n_rounds=n_rounds)
    if out is None:
        raise CalibrationError(f"fewer than two nodes, or not the reference "
                               f"{pose_graph.reference}, have centroids associated with a "
                               f"target seen by another node")
    return out


def _offset_evidence(joint: JointCalibration, period: float) -> dict[str, tuple[float, float]]:
    """name -> (fraction of a frame beyond the whole-frame lag, its z)."""
    out = {}
    for n, off in joint.time_offset_s.items():
        if n == joint.reference:
            continue
        frac = (off + joint.lag_frames.get(n, 0) * period) / period
        sd = np.sqrt(joint.time_offset_variances.get(n, np.nan)) / period
        out[n] = (float(frac), float(abs(frac) / sd) if sd > 0 else float("nan"))
    return out


def unambiguous_detections(recording: Recording, refined: MultiTargetRefinement) -> dict:
    """The associated detections of ``refined`` without those whose node
    has another centroid within :data:`SPLIT_RADIUS_M` in the same frame
    (a split body or two people close together: the association kept the
    one nearer the other nodes' centroids, on the reference's whole-frame
    clock, which pulls a node's clock offset toward the whole frame)."""
    out = {}
    for n, det in refined.detections.items():
        raw = recording.nodes[n].centroids
        rows = np.flatnonzero(refined.association.target[n] >= 0)
        xy = detection_to_local(raw.range_m, raw.omega_rad)
        order = np.argsort(raw.frame, kind="stable")
        start = np.searchsorted(raw.frame[order], raw.frame[rows], side="left")
        stop = np.searchsorted(raw.frame[order], raw.frame[rows], side="right")
        keep = np.ones(rows.size, bool)
        for i, (r, a, b) in enumerate(zip(rows, start, stop)):
            same = order[a:b]
            same = same[same != r]
            if same.size and np.min(np.linalg.norm(xy[same] - xy[r], axis=1)) < SPLIT_RADIUS_M:
                keep[i] = False
        out[n] = det.select(np.flatnonzero(keep))
    return out


def with_clock_offsets(refined: MultiTargetRefinement, recording: Recording,
                       options: JointOptions) -> tuple[MultiTargetRefinement, ClockOffsetsTried]:
    """The clock offsets beyond the whole-frame lags on the associated
    centroids of ``refined`` (a whole-frame solve of :func:`refine_associated`):
    one joint solve with ``time_offsets`` on the same detections but those
    of a node with another centroid within :data:`SPLIT_RADIUS_M` in the
    frame (:func:`unambiguous_detections`), the same noise and lags (no lag
    re-centring), started from its poses. It is kept when the
    data support it: every node's fraction within half a frame of its lag
    (the track matching's lag beat its neighbours; beyond that the
    first-order model ``F(tau) x`` does not hold) and at least one node's
    :data:`OFFSET_EVIDENCE_Z` of its sigmas from zero; else ``refined``
    (offsets at the whole frames). Returns ``(refinement, what was found)``."""
    joint = refined.joint
    if refined.detections is None or not joint.success:
        return refined, ClockOffsetsTried(outcome="no_start")
    timed_options = dataclasses.replace(options, time_offsets=True, recentre_lags=False)
    data = dict(noise=refined.noise, reference=joint.reference,
                initial_poses={n: joint.poses[n] for n in refined.detections if n in joint.poses},
                frame_period_s=recording.frame_period_s,
                lag_frames={n: int(joint.lag_frames.get(n, 0)) for n in refined.detections})
    dets = unambiguous_detections(recording, refined)
    timed = joint_calibration(dets, timed_options, **data)
    if not timed.success and timed_options.robust is not None:
        # As in the rounds: an indeterminate robust pass, Gaussian factors.
        timed = joint_calibration(dets, dataclasses.replace(timed_options, robust=None), **data)
    if not timed.success:
        return refined, ClockOffsetsTried(outcome="solve_failed", solve_status=timed.status)
    evidence = _offset_evidence(timed, recording.frame_period_s)

    def tried(outcome):
        return ClockOffsetsTried(outcome=outcome, nodes=tuple(evidence),
                                 fractions=tuple(f for f, _ in evidence.values()),
                                 z=tuple(z for _, z in evidence.values()),
                                 evidence_z=OFFSET_EVIDENCE_Z)

    period = recording.frame_period_s
    refined = dataclasses.replace(refined, clock_offsets={
        n: (f, float(np.sqrt(timed.time_offset_variances.get(n, np.nan))) / period)
        for n, (f, _) in evidence.items()})
    if any(abs(f) > 0.5 for f, _ in evidence.values()):
        return refined, tried("beyond_half_frame")
    if not any(z >= OFFSET_EVIDENCE_Z for _, z in evidence.values()):
        return refined, tried("not_determined")
    return dataclasses.replace(refined, joint=timed), tried("estimated")
