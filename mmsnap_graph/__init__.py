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
]
