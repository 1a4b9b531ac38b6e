"""Self-calibration of a radar network (docs/CONVENTIONS.md, "Pairwise self-calibration").

- :func:`closed_form_calibration`: pairwise closed form (paper eqs. 11-14)
  with a pose covariance;
- :func:`match_tracks`: which tracks of two nodes are one target, and the
  frame lag between the nodes;
- :func:`pose_graph_calibration`: N nodes from pairwise estimates, anchored
  at the reference node, with marginal covariances;
- :func:`joint_calibration`: node poses and target states from the raw
  measurements (range, spatial frequency, Doppler), refined by LM after a
  numpy pre-solve (:mod:`.presolve`) from a robust start (:mod:`.robust_start`);
- :func:`calibrate_recording`: all of the above on a
  :class:`~mmsnap_graph.data.recording.Recording`, giving a
  :class:`RecordingCalibration` (stored and read back by
  :mod:`mmsnap_graph.io.calibration`);
- :func:`estimate_noise`: each node's measurement noise from the data
  (:mod:`.noise_estimate`);
- :func:`joint_detections_multi` / :func:`refine_multi`: several people,
  associated across nodes, in the joint graph (:mod:`.multi_target`);
- :class:`DecalibrationMonitor` / :func:`monitor_recording`: notice that a
  node moved and re-calibrate it (:mod:`.monitor`).
"""

from .closed_form import (
    DEFAULT_MIN_COMMON_FRAMES,
    DEFAULT_MIN_SPREAD_M,
    PairwiseCalibration,
    alignment_jacobian,
    closed_form_calibration,
    closed_form_pose,
)
from .joint import DEFAULT_ROBUST_K, JointCalibration, joint_calibration
from .multi_refine import MultiTargetRefinement, refine_multi
from .multi_target import (
    TargetAssociation,
    TargetMapping,
    associate_targets,
    joint_detections_multi,
    target_states,
)
from .noise_estimate import estimate_noise, network_noise, temporal_noise
from .monitor import (
    ChangePoint,
    DecalibrationMonitor,
    MonitorResult,
    MonitorUpdate,
    Recalibration,
    monitor_recording,
)
from .matching import LocalTracks, TrackCandidate, TrackMatching, local_tracks, match_tracks
from .network import RecordingCalibration, calibrate_recording, residual_noise
from .pose_graph import PoseEdge, PoseGraphCalibration, pairwise_edges, pose_graph_calibration
from .poses import pose_array, pose_tangent_error, to_pose2
from .robust_start import trimmed_closed_form

__all__ = [
    "DEFAULT_MIN_COMMON_FRAMES",
    "DEFAULT_MIN_SPREAD_M",
    "PairwiseCalibration",
    "alignment_jacobian",
    "closed_form_calibration",
    "closed_form_pose",
    "DEFAULT_ROBUST_K",
    "JointCalibration",
    "joint_calibration",
    "trimmed_closed_form",
    "LocalTracks",
    "TrackCandidate",
    "TrackMatching",
    "local_tracks",
    "match_tracks",
    "RecordingCalibration",
    "calibrate_recording",
    "residual_noise",
    "PoseEdge",
    "PoseGraphCalibration",
    "pairwise_edges",
    "pose_graph_calibration",
    "pose_array",
    "pose_tangent_error",
    "to_pose2",
    "ChangePoint",
    "DecalibrationMonitor",
    "MonitorResult",
    "MonitorUpdate",
    "Recalibration",
    "monitor_recording",
    "MultiTargetRefinement",
    "refine_multi",
    "TargetAssociation",
    "TargetMapping",
    "associate_targets",
    "joint_detections_multi",
    "target_states",
    "estimate_noise",
    "network_noise",
    "temporal_noise",
]
