"""Per-node radar signal processing (no GTSAM here): configuration, FFTs,
clutter removal, OS-CFAR, clustering and per-node tracking."""

from .config import SPEED_OF_LIGHT_MPS, TABLE_I, RadarConfig

__all__ = ["SPEED_OF_LIGHT_MPS", "TABLE_I", "RadarConfig"]
