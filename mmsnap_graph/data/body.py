"""A person's size as the filters use it (metres): one place for the three
distances that decide when two detections are one body, and why they differ
(docs/CONVENTIONS.md, "A person's size").

Two kinds of quantity, not one:

- a **width** is the body's own extent. Where the positions compared carry
  their covariances, the width is all that is added to them:
  :data:`BODY_WIDTH_M`.
- a **merge radius** compares bare centroids, which carry no covariance: it
  must cover the body's extent *and* how far apart one body's centroids
  fall (a body split into torso and arm clusters, each centroid's scatter).
  It is a property of the centroids that are merged, not of the body alone:
  :data:`CENTROID_MERGE_RADIUS_M`, :data:`SCENE_MERGE_RADIUS_M`.
"""

from __future__ import annotations

__all__ = ["BODY_WIDTH_M", "CENTROID_MERGE_RADIUS_M", "SCENE_MERGE_RADIUS_M"]

#: A walker's width across the shoulders (adults 0.4-0.5 m). The fused-row
#: check of one target per body
#: (:func:`mmsnap_graph.fusion.recording.room.screen_room`, ``body_m``)
#: gives each of two fused positions a Gaussian extent of sigma
#: ``BODY_WIDTH_M / 2`` on top of their covariances, and calls rows closer
#: than this one body.
BODY_WIDTH_M = 0.5

#: Before fusion's association
#: (:func:`mmsnap_graph.fusion.recording.regroup.merge_body_detections`,
#: ``FusionOptions.merge_body_m``): a node's centroids of one frame closer
#: than this, in its own plane, are one body seen as several clusters. The
#: split halves of one person lie 0.3-0.6 m apart (the simulator's
#: ``split_distance_m``, calibrated on the real recordings; docs/SIMULATOR.md),
#: so the radius is their largest distance, 0.1 m over the width.
CENTROID_MERGE_RADIUS_M = 0.6

#: In ``mmsnap process``'s scene filters of point clouds
#: (:class:`mmsnap_graph.radar.scene.SceneConfig`, ``body_m``, the
#: ``[scene] body_m`` key): a node's centroids of one frame closer than this
#: are merged into their SNR-weighted mean, and a centroid's reach in the
#: existence check is this plus the walking speed times the time apart.
#: Fusion's merge (:data:`CENTROID_MERGE_RADIUS_M`) catches the splits it
#: leaves. Fusion's 0.6 m here gained nothing clear on the real recordings
#: of ``data/real/darksz`` (the figures of tests/app/test_real_recordings.py:
#: S2's pose, the fused rows inside the room, the frames with at most two
#: people) while the reported sigmas widened, so it stays at the width.
SCENE_MERGE_RADIUS_M = 0.5
