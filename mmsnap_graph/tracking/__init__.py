"""Target tracking: the per-node EKF (local frame) and, in later modules,
central and track-level fusion."""

from .ekf import (
    EkfConfig,
    LocalTracker,
    cv_process_noise,
    cv_transition,
    ekf_predict,
    ekf_update,
    initial_state,
    track_centroids,
)

__all__ = [
    "EkfConfig",
    "LocalTracker",
    "cv_process_noise",
    "cv_transition",
    "ekf_predict",
    "ekf_update",
    "initial_state",
    "track_centroids",
]
