"""Metrics: how good an estimate is, below the estimators and the application.

- :mod:`.metrics`: RMSE of states on common frames, pose errors, the truth
  row each estimate refers to, and the NEES with its chi-square interval;
- :mod:`.pose_bound`: what the detections of a simulated recording allow, a
  Cramer-Rao bound on the node poses (import it from the module);
- :mod:`.nominal`: calibrated poses against the nominal poses the user gave
  (far from them, with the likely cause; two nodes at one place).

Numpy and the data layer only (no GTSAM): the estimators' tests and the
``mmsnap evaluate`` command import the same definitions.
"""

from .nominal import CoincidentNodes, NominalPose, PoseDeparture, coincident_nodes, \
    nominal_poses, pose_departures
from .metrics import (
    NeesCheck,
    PoseError,
    StateErrors,
    align_frames,
    chi2_mean_interval,
    nees,
    nees_check,
    pose_error,
    pose_mapping_error,
    state_errors,
    truth_reference,
)

__all__ = [
    "NominalPose",
    "PoseDeparture",
    "CoincidentNodes",
    "nominal_poses",
    "pose_departures",
    "coincident_nodes",
    "StateErrors",
    "PoseError",
    "NeesCheck",
    "align_frames",
    "state_errors",
    "pose_error",
    "pose_mapping_error",
    "truth_reference",
    "nees",
    "chi2_mean_interval",
    "nees_check",
]
