"""One-shot fusion: each frame's range, spatial-frequency and Doppler
measurements of a target from several nodes -> its state and covariance.

- :mod:`.problem`: the one-frame problem without a solver (validation, initial
  states, the velocity degeneracy indicator; no GTSAM);
- :mod:`.oneshot`: the per-frame GTSAM graph, solved by Levenberg-Marquardt,
  with the Laplace covariance (the inverse Gauss-Newton information);
- :mod:`.batch`: the same problem vectorized over many frames;
- :mod:`.grid`: the paper's grid posterior (the check for degenerate geometry);
- :mod:`.bounds`: Cramer-Rao and Bayesian bounds;
- :mod:`.association`: which centroids of different nodes are one target;
- :mod:`.sequence`: a whole recording, frame after frame;
- :mod:`.motion_check`: a recording's rows checked against the motion of the
  neighbouring frames (ghosts, mirror solutions; docs/ROBUST.md);
- :mod:`.stream`: one frame at a time (``FrameStream``), with
  :mod:`.frame_solver` (the one-frame problem in plain floats, GTSAM's
  Levenberg-Marquardt steps) and :mod:`.stream_association` (the
  association's decisions, fast path).
"""
