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

The names below load their module on first use: importing one module of
the package (e.g. :mod:`.noise_estimate`) does not import GTSAM.
"""

from .._lazy import lazy_getattr

_LAZY = {
    "DEFAULT_MIN_COMMON_FRAMES": "closed_form",
    "DEFAULT_MIN_SPREAD_M": "closed_form",
    "PairwiseCalibration": "closed_form",
    "alignment_jacobian": "closed_form",
    "closed_form_calibration": "closed_form",
    "closed_form_pose": "closed_form",
    "DEFAULT_ROBUST_K": "joint",
    "JointCalibration": "joint",
    "joint_calibration": "joint",
    "MultiTargetRefinement": "multi_refine",
    "refine_multi": "multi_refine",
    "TargetAssociation": "multi_target",
    "TargetMapping": "multi_target",
    "associate_targets": "multi_target",
    "joint_detections_multi": "multi_target",
    "target_states": "multi_target",
    "estimate_noise": "noise_estimate",
    "network_noise": "noise_estimate",
    "temporal_noise": "noise_estimate",
    "motion_doppler_noise": "motion_noise",
    "ChangePoint": "monitor",
    "DecalibrationMonitor": "monitor",
    "MonitorResult": "monitor",
    "MonitorUpdate": "monitor",
    "Recalibration": "monitor",
    "monitor_recording": "monitor",
    "LocalTracks": "matching",
    "TrackCandidate": "matching",
    "TrackMatching": "matching",
    "local_tracks": "matching",
    "match_tracks": "matching",
    "RecordingCalibration": "network",
    "calibrate_recording": "network",
    "residual_noise": "network",
    "PoseEdge": "pose_graph",
    "PoseGraphCalibration": "pose_graph",
    "pairwise_edges": "pose_graph",
    "pose_graph_calibration": "pose_graph",
    "pose_array": "poses",
    "pose_tangent_error": "poses",
    "to_pose2": "poses",
    "trimmed_closed_form": "robust_start",
    "autocorrelation_factor": "correlation",
    "solve_point_graph": "point_graph",
    "PointEdge": "point_graph",
}

__getattr__ = lazy_getattr(__name__, _LAZY)

__all__ = list(_LAZY)
