"""What real TI radars do to people's point clouds that the clean simulator
does not (docs/SIMULATOR.md, "Real physics" and "Ghost generators").

- :mod:`.physics`: :class:`RealPhysics` (self-occlusion, correlated centroid
  errors, static scene, multipath, split clusters, misses), applied by
  :func:`~mmsnap_graph.sim.simulate_recording` by default;
- :mod:`.sparse`: the sparse clouds of TI's out-of-box demo
  (:func:`sparse_clouds`, :func:`empty_frame_mask`);
- :mod:`.ghosts`: ghost centroids for robustness tests (:func:`ghost_centroids`).
"""

from .physics import RealPhysics
from .sparse import empty_frame_mask, sparse_clouds
from .ghosts import GHOST_KINDS, ghost_centroids

__all__ = ["RealPhysics", "empty_frame_mask", "sparse_clouds", "GHOST_KINDS", "ghost_centroids"]
