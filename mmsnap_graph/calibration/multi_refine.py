"""The joint calibration graph on several people from a pose-graph result
(issue 12, Build 3): :func:`refine_multi` associates the centroids with the
pose graph's poses (:func:`~mmsnap_graph.calibration.multi_target.joint_detections_multi`),
picks the centroid noise as :func:`~mmsnap_graph.calibration.calibrate_recording`
does, and runs :func:`~mmsnap_graph.calibration.joint.joint_calibration`
unchanged on the targets' blocks of virtual frames.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np

from ..data.noise import MeasurementNoise
from ..data.recording import Recording
from ..errors import CalibrationError
from .joint import JointCalibration, joint_calibration
from .multi_target import (
    ASSOCIATION_NOISE,
    TargetAssociation,
    TargetMapping,
    joint_detections_multi,
)
from .network import residual_noise
from .pose_graph import PoseGraphCalibration

__all__ = ["MultiTargetRefinement", "refine_multi"]


@dataclass(frozen=True, kw_only=True, slots=True)
class MultiTargetRefinement:
    """Result of :func:`refine_multi`: the joint graph's result (its frames
    are virtual frames), the mapping back to ``(frame, target)``, the
    association and the measurement noise used."""

    joint: JointCalibration
    mapping: TargetMapping
    association: TargetAssociation
    noise: MeasurementNoise


def _recorded_noise(metadata) -> MeasurementNoise | None:
    """The simulator's centroid-noise metadata, when complete and valid (as
    :func:`calibrate_recording` reads it)."""
    keys = ("centroid_range_std_m", "centroid_omega_std_rad", "centroid_doppler_std_mps")
    try:
        vals = [float(metadata[k]) for k in keys]
    except (KeyError, TypeError, ValueError):
        return None
    if not all(np.isfinite(v) and v > 0 for v in vals):
        return None
    return MeasurementNoise(range_m=vals[0], omega_rad=vals[1], doppler_mps=vals[2])


def _learned_noise(dets, options) -> MeasurementNoise:
    """The association noise, then the residuals of two joint solves without
    motion factors (:func:`residual_noise`)."""
    noise = ASSOCIATION_NOISE
    for _ in range(2):
        first = joint_calibration(dets, noise=noise, **{**options, "motion": False})
        if not first.success:
            break
        noise = residual_noise(first, dets, noise=noise)
    return noise


def refine_multi(
    recording: Recording,
    pose_graph: PoseGraphCalibration,
    *,
    noise: MeasurementNoise | None = None,
    robust: str | None = "cauchy",
    motion: bool = True,
    sigma_a_mps2: float = 3.0,
    max_motion_gap_frames: int = 3,
    association: Mapping | None = None,
) -> MultiTargetRefinement:
    """The joint calibration graph on several people, from the pose graph
    (module doc).

    pose_graph : a :class:`~mmsnap_graph.calibration.pose_graph.PoseGraphCalibration`
        (e.g. ``calibrate_recording(rec, method="pose_graph").pose_graph``):
        its poses, covariances and lags drive the association and start the
        joint graph.
    noise : centroid noise of the joint graph; None: the recording's
        ``centroid_*_std`` metadata, else learned from the residuals as
        :func:`calibrate_recording` does.
    robust, motion, sigma_a_mps2, max_motion_gap_frames : the joint graph's.
    association : options of :func:`associate_targets`.
    Raises :class:`CalibrationError` when fewer than two nodes have an
    associated centroid.
    """
    names = [pose_graph.reference] + [n for n in pose_graph.poses if n != pose_graph.reference]
    dets, mapping, assoc = joint_detections_multi(
        recording, names, pose_graph.poses, pose_graph.lag_frames,
        covariances=pose_graph.covariances, max_motion_gap_frames=max_motion_gap_frames,
        **dict(association or {}))
    if dets is None:
        raise CalibrationError(f"fewer than two nodes, or not the reference "
                               f"{pose_graph.reference}, have centroids associated with a "
                               f"target seen by another node")
    options = dict(reference=pose_graph.reference,
                   initial_poses={n: pose_graph.poses[n] for n in dets}, robust=robust,
                   motion=motion, frame_period_s=recording.frame_period_s,
                   sigma_a_mps2=sigma_a_mps2, max_motion_gap_frames=max_motion_gap_frames)
    if noise is None:
        noise = _recorded_noise(recording.metadata)
        if noise is None:
            noise = _learned_noise(dets, options)
    joint = joint_calibration(dets, noise=noise, **options)
    return MultiTargetRefinement(joint=joint, mapping=mapping, association=assoc, noise=noise)
