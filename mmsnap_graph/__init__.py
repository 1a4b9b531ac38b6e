"""mmsnap_graph: self-calibration and Bayesian one-shot fusion for networks of
mmWave radars, on GTSAM factor graphs.

Layers (imports flow downward only; design/ARCHITECTURE.md):

- :mod:`factors` -- measurement models and GTSAM factors;
- :mod:`mmsnap_graph` -- estimation (one-shot fusion, calibration, tracking);
- :mod:`mmsnap_graph.radar` -- per-node signal processing (no GTSAM);
- :mod:`mmsnap_graph.sim` -- the simulator;
- :mod:`mmsnap_graph.io` -- the HDF5 recording format;
- :mod:`mmsnap_graph.cli` -- the ``mmsnap`` command line.
"""

from .errors import (
    CalibrationError,
    ConfigurationError,
    FileFormatError,
    GeometryError,
    MmsnapError,
    ValidationError,
)
from .radar.config import TABLE_I, RadarConfig
from .recording import Detections, NodeData, Recording, Tracks, Truth

__version__ = "0.1.0"

# Estimation names load on first use (they import GTSAM); the numpy-only
# layers (radar signal chain, simulator) stay importable without it.
_LAZY = {
    "MeasurementNoise": "oneshot",
    "GaussianPrior": "oneshot",
    "FusionResult": "oneshot",
    "fuse_frame": "oneshot",
    "build_frame_graph": "oneshot",
    "initial_state": "oneshot",
    "cramer_rao_bound": "bounds",
    "bayesian_bound": "bounds",
    "grid_posterior": "covariance",
    "BatchResult": "batch",
    "fuse_batch": "batch",
    "FusedSequence": "sequence",
    "fuse_recording": "sequence",
    "read_recording": "io",
    "write_recording": "io",
    "update_recording": "io",
    "simulate_recording": "sim",
    "calibrate_recording": "calibration",
    "closed_form_calibration": "calibration",
    "joint_calibration": "calibration",
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
