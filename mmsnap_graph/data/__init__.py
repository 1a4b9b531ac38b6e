"""The data every layer shares: recordings (detections, tracks, truth), the
radar configuration, and the result types of the estimators.

- :mod:`.recording`: :class:`Detections`, :class:`Tracks`, :class:`NodeData`,
  :class:`Truth`, :class:`Recording` (the in-memory model of a recording);
- :mod:`.radar_config`: :class:`RadarConfig` (the paper's Table I by default);
- :mod:`.noise`: :class:`MeasurementNoise`, :class:`GaussianPrior`;
- :mod:`.results`: :class:`Status` (the one status enum), :class:`FusedSequence`;
- :mod:`.solution`: :class:`FusionSolution`, the one record of a one-shot solve;
- :mod:`.calibration`: :class:`PairwiseCalibration`, :class:`RecordingCalibration`
  (self-calibration's results), with :mod:`.calibration_facts`:
  :class:`CalibrationStatus` and the typed facts they report;
- :mod:`.body`: a person's size as the filters use it (a width, and the merge
  radii of centroids).
"""

from .radar_config import SPEED_OF_LIGHT_MPS, TABLE_I, RadarConfig, TiProfile
from .recording import Detections, NodeData, Recording, Tracks, Truth
from .calibration import PairwiseCalibration, RecordingCalibration
from .calibration_facts import CalibrationStatus
from .results import DEGENERACY_THRESHOLD, FusedSequence, Status
from .solution import FusionSolution

__all__ = [
    "SPEED_OF_LIGHT_MPS",
    "TABLE_I",
    "RadarConfig",
    "TiProfile",
    "Detections",
    "NodeData",
    "Recording",
    "Tracks",
    "Truth",
    "Status",
    "DEGENERACY_THRESHOLD",
    "FusionSolution",
    "FusedSequence",
    "CalibrationStatus",
    "PairwiseCalibration",
    "RecordingCalibration",
]
