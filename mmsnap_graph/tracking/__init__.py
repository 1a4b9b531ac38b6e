"""Target tracking: the per-node EKF (local frame, :mod:`.ekf`), the central
tracker over one-shot estimates (:mod:`.central`), the person ids it gives
fused rows (:mod:`.person_ids`) and the paper's track-level fusion benchmark
(:mod:`.track_fusion`).

The central tracker and track fusion load on first use, so the per-node
signal chain (which uses the EKF) does not import GTSAM. The motion model
(transition, process noise) is :mod:`factors.motion`.
"""

from .ekf import (
    EkfConfig,
    LocalTracker,
    ekf_predict,
    ekf_update,
    track_centroids,
    track_initial_state,
)

_LAZY = {
    "CentralConfig": "central",
    "CentralTracker": "central",
    "FixedLagTracker": "central",
    "track_fused": "central",
    "PersonIds": "person_ids",
    "assign_person_ids": "person_ids",
    "transform_tracks": "track_fusion",
    "covariance_intersection": "track_fusion",
    "TrackFusion": "track_fusion",
    "fuse_tracks": "track_fusion",
}

from .._lazy import lazy_getattr

__getattr__ = lazy_getattr(__name__, _LAZY)


__all__ = [
    *_LAZY,
    "EkfConfig",
    "LocalTracker",
    "ekf_predict",
    "ekf_update",
    "track_initial_state",
    "track_centroids",
]
