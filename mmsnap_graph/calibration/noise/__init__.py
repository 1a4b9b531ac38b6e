"""Each node's measurement noise from a recording's own data.

- :mod:`.estimate`: :func:`~.estimate.estimate_noise` (network and temporal
  estimators of the range, spatial-frequency and Doppler sigmas);
- :mod:`.tails`: the second moment of heavy-tailed centroid noise;
- :mod:`.motion`: the Doppler sigmas with the target's motion estimated
  jointly;
- :mod:`.sequences`: each node's single-target sequences and the ghosts
  in them;
- :mod:`.depth`: the range offset (a body's reflection depth) at fixed
  node poses;
- :mod:`.frame_states`: each frame's least-squares target state at known
  poses (the estimators' inner solve).

The public names are exported by :mod:`mmsnap_graph.calibration`.
"""
