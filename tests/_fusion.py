"""Fusion configurations for the tests, by the settings each test is about.

:func:`config` builds the :class:`~mmsnap_graph.fusion.config.FusionConfig`
of a test from the few settings it names; what it leaves out is per-frame
one-shot fusion (:data:`~mmsnap_graph.fusion.config.PLAIN_CONFIG`): no robust
fit, and only the checks the test asks for, except that a robust fit brings
the motion check (with its coverage check) and the body merge, as the
recording drivers' defaults do. :func:`stream_config` is the same for a
:class:`~mmsnap_graph.fusion.stream.frame_stream.FrameStream` (no check).
"""

from __future__ import annotations

from mmsnap_graph.data.body import CENTROID_MERGE_RADIUS_M
from mmsnap_graph.data.noise import GaussianPrior
from mmsnap_graph.fusion.config import (AssociationOptions, CoverageCheck, DuplicateCheck,
                                        FusionConfig, LearnedWalls, MotionCheck, RoomCheck,
                                        SplitCheck)
from mmsnap_graph.fusion.options import FusionOptions

__all__ = ["config", "stream_config", "solved", "frame_of", "PAPER_PRIOR"]

PAPER_PRIOR = GaussianPrior()
_SOLVE = {"lm", "covariance", "grid_points_per_axis", "grid_half_width_sigmas",
          "step_tolerance", "newton_after", "chunk_size", "solver", "block_rows"}


def config(*, mode: str = "map", prior=PAPER_PRIOR, robust=None, options=None,
           motion_check=None, body_merge=None, merge_body_m=CENTROID_MERGE_RADIUS_M,
           coverage_check=True, coverage_reach_m=None, gate_probability=0.999, source="centroids", split_check=True,
           bounds=None, static_bounds=None, in_front=False, walls=False, body_m=None,
           **solve) -> FusionConfig:
    """The FusionConfig of these settings (module docstring); ``solve``:
    fields of :class:`FusionOptions` (or ``options``, one)."""
    unknown = set(solve) - _SOLVE
    if unknown:
        raise TypeError(f"config(): unknown settings {sorted(unknown)}")
    if options is not None and solve:
        raise TypeError("config(): options or solve fields, not both")
    solve_options = options if options is not None else FusionOptions(**solve)
    motion = (robust is not None) if motion_check is None else bool(motion_check)
    merge = (robust is not None) if body_merge is None else bool(body_merge)
    checks = [SplitCheck()] if split_check else []
    if motion:
        checks.append(MotionCheck())
        if coverage_check:
            checks.append(CoverageCheck(reach_m=coverage_reach_m))
    if bounds is not None or static_bounds is not None or in_front:
        checks.append(RoomCheck(bounds=bounds, static_bounds=static_bounds, in_front=in_front))
    if walls and bounds is None:
        checks.append(LearnedWalls())
    if body_m is not None:
        checks.append(DuplicateCheck(body_m=body_m))
    return FusionConfig(
        solve=solve_options, prior=None if mode == "ml" else prior, robust=robust,
        association=AssociationOptions(gate_probability=gate_probability, source=source,
                                       merge_body_m=merge_body_m if merge else None),
        checks=tuple(checks))


def stream_config(*, prior=PAPER_PRIOR, solver="scalar", gate_probability=0.999,
                  **settings) -> FusionConfig:
    """A stream's FusionConfig: per-frame one-shot fusion, no check unless asked."""
    settings.setdefault("split_check", False)
    return config(prior=prior, solver=solver, gate_probability=gate_probability, **settings)


def solved(poses, z, *, solver: str = "gtsam", robust=None, options=None, **problem):
    """``z`` ((N, 3): one frame, or (F, N, 3)) of the nodes at ``poses``
    solved through the contract (:func:`~mmsnap_graph.fusion.solve.robust_solve`
    with ``solver``; ``options`` a FusionOptions whose solver is replaced);
    ``problem``: the other fields of
    :class:`~mmsnap_graph.fusion.frame_problem.FrameProblem` (a single
    frame's ``initial_state`` may be (4,))."""
    import dataclasses

    import numpy as np

    from mmsnap_graph.fusion.frame_problem import FrameProblem
    from mmsnap_graph.fusion.solve import robust_solve

    opts = FusionOptions(solver=solver) if options is None else dataclasses.replace(
        options, solver=solver)
    x0 = problem.get("initial_state")
    if x0 is not None and np.ndim(x0) == 1:
        problem["initial_state"] = np.asarray(x0, dtype=float)[None]
    return robust_solve(FrameProblem(poses=poses, measurements=z, **problem), opts, robust)


def frame_of(solution, f: int = 0):
    """Frame ``f`` of a :class:`~mmsnap_graph.data.solution.FusionSolution`
    with its frame axis dropped (a namespace of its fields), for tests of one
    frame."""
    from types import SimpleNamespace

    names = ("state", "covariance", "status", "success", "message", "iterations",
             "final_cost", "initial_state", "whitened_residuals", "degeneracy", "rejected")
    out = {name: getattr(solution, name)[f] for name in names}
    grid = solution.grid_covariance
    out["grid_covariance"] = None if grid is None else grid[f]
    return SimpleNamespace(**out)
