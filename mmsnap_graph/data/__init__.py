"""The data every layer shares: recordings (detections, tracks, truth), the
radar configuration, and the result types of the estimators.

- :mod:`.recording`: :class:`Detections`, :class:`Tracks`, :class:`NodeData`,
  :class:`Truth`, :class:`Recording` (the in-memory model of a recording);
- :mod:`.radar_config`: :class:`RadarConfig` (the paper's Table I by default).
"""

from .radar_config import SPEED_OF_LIGHT_MPS, TABLE_I, RadarConfig
from .recording import Detections, NodeData, Recording, Tracks, Truth

__all__ = [
    "SPEED_OF_LIGHT_MPS",
    "TABLE_I",
    "RadarConfig",
    "Detections",
    "NodeData",
    "Recording",
    "Tracks",
    "Truth",
]
