"""mmsnap_graph: self-calibration and Bayesian one-shot fusion for networks of
mmWave radars, on GTSAM factor graphs.

Layers (imports flow downward only; docs/CONVENTIONS.md, "Layers"):

- :mod:`factors` -- measurement models and GTSAM factors;
- :mod:`mmsnap_graph` -- estimation (one-shot fusion, calibration, tracking);
- :mod:`mmsnap_graph.radar` -- per-node signal processing (no GTSAM);
- :mod:`mmsnap_graph.sim` -- the simulator;
- :mod:`mmsnap_graph.io` -- the HDF5 recording format;
- :mod:`mmsnap_graph.app.cli` -- the ``mmsnap`` command line.
"""

from .errors import (
    CalibrationError,
    ConfigurationError,
    FileFormatError,
    GeometryError,
    MmsnapError,
    ValidationError,
)
from .data.radar_config import TABLE_I, RadarConfig
from .data.recording import Detections, NodeData, Recording, Tracks, Truth

__version__ = "0.1.0"

# Estimation names load on first use (they import GTSAM); the numpy-only
# layers (radar signal chain, simulator) stay importable without it.
_LAZY = {
    "MeasurementNoise": "data.noise",
    "GaussianPrior": "data.noise",
    "Status": "data.results",
    "FusionSolution": "data.solution",
    "FusedSequence": "data.results",
    "measurement_information": "data.results",
    "NoiseEstimate": "data.noise",
    "CalibrationStatus": "data.calibration_facts",
    "PairwiseCalibration": "data.calibration",
    "RecordingCalibration": "data.calibration",
    "estimate_noise": "calibration",
    "FrameProblem": "fusion.frame_problem",
    "initial_states": "fusion.frame_problem",
    "FusionOptions": "fusion.options",
    "RobustOptions": "fusion.options",
    "solve": "fusion.solve",
    "robust_solve": "fusion.solve",
    "build_frame_graph": "fusion.solvers.gtsam_graph",
    "cramer_rao_bound": "fusion.bounds",
    "bayesian_bound": "fusion.bounds",
    "grid_posterior": "fusion.grid",
    "fuse_recording": "fusion.recording.sequence",
    "read_fused": "io.fused",
    "write_fused": "io.fused",
    "read_recording": "io",
    "write_recording": "io",
    "update_recording": "io",
    "simulate_recording": "sim",
    "calibrate_recording": "calibration",
    "closed_form_calibration": "calibration",
    "joint_calibration": "calibration",
    "JointOptions": "calibration",
    "MatchingOptions": "calibration",
    "match_tracks": "calibration",
    "pose_graph_calibration": "calibration",
}


from ._lazy import lazy_getattr

__getattr__ = lazy_getattr(__name__, _LAZY)


__all__ = [
    "MmsnapError",
    "ValidationError",
    "GeometryError",
    "ConfigurationError",
    "FileFormatError",
    "CalibrationError",
    "RadarConfig",
    "TABLE_I",
    "Detections",
    "Tracks",
    "NodeData",
    "Truth",
    "Recording",
    *_LAZY,
]
