"""One-shot fusion: each frame's range, spatial-frequency and Doppler
measurements of a target from several nodes -> its state and covariance.

The package is laid out by stage:

- :mod:`.options`: :class:`FusionOptions`, :class:`RobustOptions` and
  :class:`NetworkCalibration` (poses, covariances, clock and range offsets), taken
  by every entry point; :mod:`.config`: :class:`FusionConfig`, how a recording
  or a stream is fused (the association, the solve, the checks as components);
- the one-shot problem and the one solve contract (no GTSAM):
  :mod:`.frame_problem` (:class:`FrameProblem`, validated once, batched over
  frames; its one initial state), :mod:`.solve` (:func:`solve` with any
  solver, :func:`robust_solve` the robust fit around it; the record is
  :class:`~mmsnap_graph.data.solution.FusionSolution`), :mod:`.problem` (the
  validation checks), :mod:`.degeneracy` (the
  velocity degeneracy indicator), :mod:`.robust` (kernels and the residual
  gate), :mod:`.association` (which centroids of different nodes are one
  target);
- checks and references: :mod:`.grid` (the paper's grid posterior, the check
  for degenerate geometry), :mod:`.bounds` (Cramer-Rao and Bayesian bounds);
- :mod:`.solvers`: three solvers of the same problem, tested equal --
  GTSAM (:mod:`.solvers.gtsam_graph`, Levenberg-Marquardt and the Laplace
  covariance from ``Marginals``; :mod:`.solvers.gtsam_poses` for uncertain
  node poses), vectorized numpy over many frames (:mod:`.solvers.vectorized`,
  :mod:`.solvers.vectorized_lm`, :mod:`.solvers.vectorized_poses`) and plain
  floats for one frame at a time (:mod:`.solvers.scalar`), each called
  through :func:`solve`, with their settings (:mod:`.solvers.settings`: one
  name per solver, the Levenberg-Marquardt settings they all follow) and the
  shared assessment of a solved frame (:mod:`.solvers.assess`);
- :mod:`.recording`: a whole recording -- :mod:`.recording.sequence`
  (``fuse_recording``), :mod:`.recording.rows` (its rows while they are
  built), :mod:`.recording.timing` (clock alignment),
  :mod:`.recording.motion_check` (rows checked against the motion of the
  neighbouring frames: ghosts, mirror solutions; docs/ROBUST.md),
  :mod:`.recording.split_check` (one target split by the association);
- :mod:`.stream`: one frame at a time -- :mod:`.stream.frame_stream`
  (``FrameStream``) and :mod:`.stream.association` (the association's
  decisions, fast path).

The public names below load their module on first use, so importing
:mod:`mmsnap_graph.fusion` imports neither GTSAM nor scipy.
"""

from .._lazy import lazy_getattr

_LAZY = {
    # the options and the solvers' contract
    "FusionOptions": "options",
    "RobustOptions": "options",
    "NetworkCalibration": "options",
    "DEFAULT_OPTIONS": "options",
    "robust_options": "options",
    "FusionConfig": "config",
    "AssociationOptions": "config",
    "MotionCheck": "config",
    "SplitCheck": "config",
    "CoverageCheck": "config",
    "UnplacedCheck": "config",
    "RoomCheck": "config",
    "LearnedWalls": "config",
    "DuplicateCheck": "config",
    "DEFAULT_CONFIG": "config",
    "PLAIN_CONFIG": "config",
    "SOLVERS": "solvers.settings",
    "check_solver": "solvers.settings",
    "LevenbergMarquardtSettings": "solvers.settings",
    "LM_SETTINGS": "solvers.settings",
    "FrameProblem": "frame_problem",
    "initial_states": "frame_problem",
    "whitened_residuals": "frame_problem",
    "solve": "solve",
    "robust_solve": "solve",
    # the one-frame problem
    "check_poses": "problem",
    "check_observed": "problem",
    "check_noise": "problem",
    "check_node_noise": "problem",
    "node_sigmas": "problem",
    "check_pose_covariances": "problem",
    "check_prior": "problem",
    "validate_frame": "problem",
    "validate_frames": "problem",
    "valid_rows": "problem",
    "condition_2x2": "degeneracy",
    "velocity_degeneracy": "degeneracy",
    "ROBUST_CHOICES": "robust",
    "RESIDUAL_GATE_PROBABILITY": "robust",
    "check_robust": "robust",
    "check_robust_k": "robust",
    "residual_gate_threshold": "robust",
    "kernel_weight_and_loss": "robust",
    "node_d2": "robust",
    "FrameAssociation": "association",
    "group_distance2": "association",
    "detection_position_covariance": "association",
    "associate_frame": "association",
    "gate_threshold": "association",
    "detection_information": "association",
    "MIN_VARIANCE_M2": "association",
    "MAX_CONDITION": "association",
    # checks and references
    "GridPosterior": "grid",
    "grid_posterior": "grid",
    "neg_log_posterior": "grid",
    "fisher_information": "bounds",
    "cramer_rao_bound": "bounds",
    "bayesian_bound": "bounds",
    # the solvers
    "STATE_KEY": "solvers.gtsam_graph",
    "build_frame_graph": "solvers.gtsam_graph",
    "lm_params": "solvers.gtsam_graph",
    "pose_key": "solvers.gtsam_poses",
    "build_pose_aware_graph": "solvers.gtsam_poses",
    "pose_aware_covariance": "solvers.gtsam_poses",
    "NEWTON_DECREMENT_TOLERANCE": "solvers.assess",
    "residuals_and_degeneracy": "solvers.assess",
    "kernel_weight": "solvers.assess",
    "positive_definite": "solvers.assess",
    "assess_fit": "solvers.assess",
    "pose_information_term": "solvers.vectorized_poses",
    "propagate_pose_covariance": "solvers.vectorized_poses",
    "STATE_TOLERANCE": "solvers.scalar",
    "COVARIANCE_TOLERANCE": "solvers.scalar",
    # a whole recording
    "fuse_recording": "recording.sequence",
    "recording_poses": "recording.sequence",
    "group_detections": "recording.sequence",
    "MOTION_WINDOW_FRAMES": "recording.motion_check",
    "MOTION_MIN_SUPPORT": "recording.motion_check",
    "MOTION_GATE_PROBABILITY": "recording.motion_check",
    "MOTION_ACCEL_SIGMA_MPS2": "recording.motion_check",
    "MOTION_FLAG_STATUS": "recording.motion_check",
    "MOTION_CONTEXT_FRAMES": "recording.motion_check",
    "MOTION_MAX_LEFT_OUT": "recording.motion_check",
    "Refit": "recording.motion_check",
    "apply_motion_check": "recording.motion_check",
    "split_singles": "recording.split_check",
    "split_rows": "recording.split_check",
    "FusedRows": "recording.rows",
    "SPLIT_MESSAGE": "recording.split_check",
    "split_offset": "recording.timing",
    "align_detections": "recording.timing",
    "align_recording": "recording.timing",
    # one frame at a time
    "StreamUpdate": "stream.frame_stream",
    "FrameStream": "stream.frame_stream",
    "recording_frames": "stream.frame_stream",
    "StreamAssociator": "stream.association",
}

__getattr__ = lazy_getattr(__name__, _LAZY)

__all__ = list(_LAZY)
