"""Per-node radar signal processing (no GTSAM here): configuration, FFTs,
clutter removal, OS-CFAR, clustering, and the whole per-node chain.

- :mod:`.spectrum`: range/Doppler FFTs, static clutter removal, TDM-MIMO
  correction, angle estimation;
- :mod:`.cfar`: 2D OS-CFAR;
- :mod:`.cluster`: torso DBSCAN centroids;
- :mod:`.chain`: cube -> point cloud -> centroids (:func:`process_cubes`).

The radar configuration (:class:`RadarConfig`) lives in
:mod:`mmsnap_graph.data` and is re-exported here; running the chain and the
local EKF over recordings and files is :mod:`mmsnap_graph.app.pipeline`.

The chain's names load on first use, so that importing the configuration
(every layer does) does not import scikit-learn.
"""

from ..data.radar_config import SPEED_OF_LIGHT_MPS, TABLE_I, RadarConfig

_LAZY = {
    "ChainConfig": "chain",
    "ChainResult": "chain",
    "detect_frame": "chain",
    "point_cloud_of_cube": "chain",
    "process_cubes": "chain",
    "unambiguous_speed_mps": "chain",
    "doppler_near_limit": "chain",
    "CfarConfig": "cfar",
    "ClusterConfig": "cluster",
    "torso_centroids": "cluster",
    "range_doppler": "spectrum",
}


from .._lazy import lazy_getattr

__getattr__ = lazy_getattr(__name__, _LAZY)


__all__ = ["SPEED_OF_LIGHT_MPS", "TABLE_I", "RadarConfig", *_LAZY]
