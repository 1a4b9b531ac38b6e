"""Self-calibration of a radar network (docs/CONVENTIONS.md, "Pairwise self-calibration").

- :func:`closed_form_calibration`: pairwise closed form (paper eqs. 11-14)
  with a pose covariance (a :class:`~mmsnap_graph.data.calibration.PairwiseCalibration`);
- :func:`match_tracks`: which tracks of two nodes are one target, and the
  frame lag between the nodes;
- :func:`pose_graph_calibration`: N nodes from pairwise estimates, anchored
  at the reference node, with marginal covariances;
- :func:`joint_calibration`: node poses and target states from the raw
  measurements (range, spatial frequency, Doppler), refined by LM after a
  numpy pre-solve (:mod:`.joint.presolve`) from a robust start (:mod:`.joint.robust_start`);
- :func:`calibrate_recording`: all of the above on a
  :class:`~mmsnap_graph.data.recording.Recording`, giving a
  :class:`~mmsnap_graph.data.calibration.RecordingCalibration` (stored and
  read back by :mod:`mmsnap_graph.io.calibration`), with a status and typed
  facts (:mod:`mmsnap_graph.data.calibration_facts`);
- :func:`estimate_noise`: each node's measurement noise from the data
  (:mod:`.noise.estimate`); :func:`noise_at_poses`: the same at given node
  poses, the centroids associated across nodes first when several share a
  frame (``mmsnap calibrate`` and ``mmsnap noise``);
- :func:`joint_detections_multi` / :func:`refine_multi`: several people,
  associated across nodes, in the joint graph (:mod:`.joint.multi_target`);
- :class:`DecalibrationMonitor` / :func:`monitor_recording`: notice that a
  node moved and re-calibrate it (:mod:`.monitor.decalibration`).

The names below load their module on first use: importing one module of
the package (e.g. :mod:`.noise.estimate`) does not import GTSAM.
"""

from .._lazy import lazy_getattr

_LAZY = {
    "DEFAULT_MIN_COMMON_FRAMES": "pairwise.closed_form",
    "DEFAULT_MIN_SPREAD_M": "pairwise.closed_form",
    "alignment_jacobian": "pairwise.closed_form",
    "closed_form_calibration": "pairwise.closed_form",
    "closed_form_pose": "pairwise.closed_form",
    "DEFAULT_ROBUST_K": "joint.options",
    "JointOptions": "joint.options",
    "JointCalibration": "joint.solve",
    "joint_calibration": "joint.solve",
    "MultiTargetRefinement": "joint.multi_refine",
    "refine_multi": "joint.multi_refine",
    "AssociationOptions": "joint.multi_target",
    "TargetAssociation": "joint.multi_target",
    "TargetMapping": "joint.multi_target",
    "associate_targets": "joint.multi_target",
    "joint_detections_multi": "joint.multi_target",
    "target_states": "joint.multi_target",
    "estimate_noise": "noise.estimate",
    "network_noise": "noise.estimate",
    "temporal_noise": "noise.estimate",
    "motion_doppler_noise": "noise.motion",
    "ChangePoint": "monitor.decalibration",
    "DecalibrationMonitor": "monitor.decalibration",
    "MonitorResult": "monitor.decalibration",
    "MonitorUpdate": "monitor.decalibration",
    "Recalibration": "monitor.decalibration",
    "monitor_recording": "monitor.decalibration",
    "MatchingOptions": "pairwise.matching_options",
    "LocalTracks": "pairwise.matching",
    "TrackCandidate": "pairwise.matching",
    "TrackMatching": "pairwise.matching",
    "local_tracks": "pairwise.matching",
    "match_tracks": "pairwise.matching",
    "POINT_JOINT_OPTIONS": "network",
    "PEOPLE_JOINT_OPTIONS": "network",
    "JOINT_OPTIONS_BY_TARGETS": "network",
    "joint_options_for": "network",
    "calibrate_recording": "network",
    "noise_at_poses": "network",
    "residual_noise": "joint.residual_noise",
    "pairwise_edges": "pairwise.pose_graph",
    "pose_graph_calibration": "pairwise.pose_graph",
    "pose_array": "poses",
    "pose_tangent_error": "poses",
    "to_pose2": "poses",
    "trimmed_closed_form": "joint.robust_start",
    "autocorrelation_factor": "pairwise.effective_samples",
    "solve_point_graph": "pairwise.point_graph",
    "PointEdge": "pairwise.point_graph",
}

__getattr__ = lazy_getattr(__name__, _LAZY)

__all__ = list(_LAZY)
