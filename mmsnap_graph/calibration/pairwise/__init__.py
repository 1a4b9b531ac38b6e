"""Pairwise calibration: node poses from the local tracks of node pairs.

- :mod:`.closed_form`: the pose of one node in another's frame from one
  common target, in closed form, with its covariance;
- :mod:`.matching` (thresholds in :mod:`.matching_options`): which tracks of
  two nodes are one target, and the frame lag between the nodes;
- :mod:`.centroid_points`: centroid tracks in a node's frame without the bias
  of the angle's noise;
- :mod:`.effective_samples`: the effective-sample-size correction of the pose
  covariances for frame-to-frame correlated residuals;
- :mod:`.pose_graph`: every node's pose from the pairwise estimates, anchored
  at the reference node; :mod:`.point_graph`: the same from the matched
  points of all pairs at once.

The public names are exported by :mod:`mmsnap_graph.calibration`.
"""
