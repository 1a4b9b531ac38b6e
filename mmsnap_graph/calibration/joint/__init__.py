"""Joint calibration: node poses and target states from the raw measurements.

- :mod:`.solve`: :func:`~.solve.joint_calibration`, the joint graph's solve
  (robust passes, outlier test, marginal covariances);
- :mod:`.graph`: the graph in GTSAM (keys, factors, values, covariances);
- :mod:`.presolve`: the numpy pre-solve of the same graph;
- :mod:`.robust_start`: the starting poses and states;
- :mod:`.multi_target` and :mod:`.multi_refine`: several people, associated
  across nodes, in rounds of association and joint solve;
- :mod:`.residual_noise`: the measurement noise from a solution's residuals.

The public names are exported by :mod:`mmsnap_graph.calibration`.
"""
