"""Three solvers of the one-frame problem of :mod:`mmsnap_graph.fusion.problem`,
deliberately kept and tested equal (same statuses, states and covariances):

- GTSAM: :mod:`.gtsam_graph` (the factor graph, Levenberg-Marquardt and the
  Laplace covariance from ``Marginals``; ``fuse_frame``) and
  :mod:`.gtsam_poses` (node poses as uncertain variables);
- vectorized numpy over many frames: :mod:`.vectorized` (``fuse_batch``),
  :mod:`.vectorized_lm` (its Levenberg-Marquardt iterations) and
  :mod:`.vectorized_poses` (pose uncertainty by linear propagation);
- plain floats, one frame at a time: :mod:`.scalar` (``FrameSolver``, the
  streaming path);

and :mod:`.assess`, the checks that make a solved frame a success.
"""
