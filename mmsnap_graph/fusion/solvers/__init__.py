"""Three solvers of the one-shot problem
(:class:`~mmsnap_graph.fusion.frame_problem.FrameProblem`), each the
``solve_frames`` behind one ``solver`` name of
:func:`mmsnap_graph.fusion.solve.solve`, deliberately kept and tested equal
through it (same statuses, states and covariances):

- ``"gtsam"``, the reference: :mod:`.gtsam_graph` (the factor graph,
  Levenberg-Marquardt and the Laplace covariance from ``Marginals``) and
  :mod:`.gtsam_poses` (node poses as uncertain variables);
- ``"vectorized"``, numpy over many frames: :mod:`.vectorized`,
  :mod:`.vectorized_lm` (its Levenberg-Marquardt iterations) and
  :mod:`.vectorized_poses` (pose uncertainty by linear propagation);
- ``"scalar"``, plain floats, one frame at a time: :mod:`.scalar` (the
  streaming path);

and :mod:`.assess`, the checks that make a solved frame a success.
"""
