"""Per-node radar signal processing (no GTSAM here): configuration, FFTs,
clutter removal, OS-CFAR, clustering, and the whole per-node chain.

- :mod:`.config`: :class:`RadarConfig` (Table I by default);
- :mod:`.spectrum`: range/Doppler FFTs, static clutter removal, TDM-MIMO
  correction, angle estimation;
- :mod:`.cfar`: 2D OS-CFAR;
- :mod:`.cluster`: torso DBSCAN centroids;
- :mod:`.chain`: cube -> point cloud -> centroids (:func:`process_cubes`);
- :mod:`.pipeline`: the chain plus the local EKF on nodes, recordings and files.

The chain's names load on first use, so that importing the configuration
(every layer does) does not import scikit-learn.
"""

from .config import SPEED_OF_LIGHT_MPS, TABLE_I, RadarConfig

_LAZY = {
    "ChainConfig": "chain",
    "ChainResult": "chain",
    "FrameStatus": "chain",
    "detect_frame": "chain",
    "point_cloud_of_cube": "chain",
    "process_cubes": "chain",
    "CfarConfig": "cfar",
    "ClusterConfig": "cluster",
    "torso_centroids": "cluster",
    "range_doppler": "spectrum",
    "NodeReport": "pipeline",
    "process_node": "pipeline",
    "process_recording": "pipeline",
    "track_node": "pipeline",
    "track_recording": "pipeline",
    "process_file": "pipeline",
}


from .._lazy import lazy_getattr

__getattr__ = lazy_getattr(__name__, _LAZY)


__all__ = ["SPEED_OF_LIGHT_MPS", "TABLE_I", "RadarConfig", *_LAZY]
