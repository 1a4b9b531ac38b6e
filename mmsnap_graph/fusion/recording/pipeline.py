"""The one pipeline of recording fusion, after the association: solve each
target, then the checks of :class:`~mmsnap_graph.fusion.config.FusionConfig`.

Three drivers run it (docs/STREAMING.md, "One pipeline"):

- in memory, :func:`~mmsnap_graph.fusion.recording.sequence.fuse_recording`:
  :func:`run_pipeline` on every row of the recording;
- windowed over a file, :func:`mmsnap_graph.app.chunked_fuse.fuse_file`: the
  same on each window read with :attr:`FusionConfig.context_frames` frames of
  context on each side, keeping the window's own rows;
- one frame at a time, :class:`~mmsnap_graph.fusion.stream.frame_stream.FrameStream`:
  :func:`solve_groups` once per frame, then :func:`check_rows` on the frames it
  holds, and :func:`screen_rows` on the frame it decides.

The stages:

1. :func:`solve_groups`: the one-shot solve of every group (robust fit
   included), flagging a row that cannot be fused;
2. :func:`check_rows`: the checks that look at neighbouring frames and at the
   association (motion, split, coverage), on the solved rows;
3. the grid covariance (``covariance="grid"``) of the rows kept;
4. :func:`screen_rows`: the checks in the reference frame (room, learned walls,
   duplicates) on the :class:`~mmsnap_graph.data.results.FusedSequence`.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from ...data.results import FusedSequence, Status
from ...errors import MmsnapError
from ..frame_problem import SMALL_PROBLEM_ROWS, FrameProblem
from ..options import FusionOptions
from ..solve import robust_solve, solve
from ..config import (CoverageCheck, DuplicateCheck, FusionConfig, LearnedWalls, MotionCheck,
                      RoomCheck, SplitCheck, UnplacedCheck)
from ..grid import grid_posterior
from ..problem import node_sigmas, valid_rows
from ..robust import RESIDUAL_GATE_PROBABILITY
from .coverage import uncovered_rows
from .motion_check import apply_motion_check
from .room import DEFAULT_BODY_M, RoomReport, screen_room
from .rows import FusedRows
from .split_check import SPLIT_MESSAGE, split_rows
from .unplaced import UNPLACED_MESSAGE, unplaced_rows

__all__ = ["FusionNetwork", "solve_groups", "check_rows", "check_placement", "screen_rows",
           "fuse_rows", "run_pipeline", "fused_sequence"]


@dataclass(frozen=True, kw_only=True, slots=True)
class FusionNetwork:
    """What the pipeline knows of the network, validated once by its driver.

    node_names : N names; problem : the network's
    :class:`~mmsnap_graph.fusion.frame_problem.FrameProblem` without frames
    (the node poses (N, 3), their noise and covariances, the prior of the
    configuration): each solve's problem is made from it with
    :meth:`~mmsnap_graph.fusion.frame_problem.FrameProblem.with_frames`;
    frame_period_s : s.
    """

    node_names: tuple
    problem: FrameProblem
    frame_period_s: float

    @classmethod
    def make(cls, node_names, poses, noise, pose_covariances, prior,
             frame_period_s: float) -> "FusionNetwork":
        """The network of N nodes (validated: poses (N, 3), ``noise`` one
        :class:`MeasurementNoise` or N, ``pose_covariances`` (N, 3, 3) or None,
        ``prior`` a GaussianPrior or None)."""
        n = len(node_names)
        problem = FrameProblem(poses=poses, measurements=np.zeros((0, n, 3)),
                               observed=np.zeros((0, n), dtype=bool), noise=noise, prior=prior,
                               pose_covariances=pose_covariances)
        return cls(node_names=tuple(node_names), problem=problem,
                   frame_period_s=float(frame_period_s))

    @property
    def poses(self) -> NDArray:
        """(N, 3) the node poses."""
        return self.problem.poses

    @property
    def noise(self) -> tuple:
        """N :class:`MeasurementNoise`, node order."""
        return self.problem.noise

    @property
    def pose_covariances(self) -> NDArray | None:
        """(N, 3, 3) or None (exact poses)."""
        return self.problem.pose_covariances


def progress_bar(total: int, desc: str, progress: bool | None):
    """A tqdm bar on stderr (``progress`` None: when stderr is a terminal)."""
    from tqdm import tqdm  # deferred: only a progress bar needs it

    disable = (not sys.stderr.isatty()) if progress is None else not progress
    return tqdm(total=total, desc=desc, unit="frame", disable=disable)


def _laplace(config: FusionConfig) -> FusionOptions:
    """The solve options of the rows (the grid covariance comes after the checks)."""
    solve = config.solve
    return solve if solve.covariance == "laplace" else replace(solve, covariance="laplace")


def solve_groups(z: NDArray, observed: NDArray, net: FusionNetwork, config: FusionConfig, *,
                 bar=None) -> FusedRows:
    """The one-shot solve of K groups (:func:`~mmsnap_graph.fusion.solve.robust_solve`
    with ``config.solve``'s solver and ``config.robust``): ``z`` (K, N, 3),
    ``observed`` (K, N) bool; the Laplace covariance (the grid one comes after
    the checks). A row with an invalid observed measurement (range 0, say) is
    flagged, not fused; ``config.solve.block_rows`` rows are solved at a time."""
    k = z.shape[0]
    options = _laplace(config)
    block_rows = config.solve.block_rows
    if 0 < k <= block_rows and k * observed.shape[1] <= SMALL_PROBLEM_ROWS:
        # A frame's few groups (the stream): one solve, its rows as they are.
        try:
            problem = net.problem.with_frames(z, observed)
        except MmsnapError:  # an invalid measurement: the rows one by one below
            pass
        else:
            return FusedRows.of(robust_solve(problem, options, config.robust))
    out = FusedRows(k, observed.shape[1])
    invalid = (observed & ~valid_rows(z)).any(axis=1) if k else np.zeros(0, dtype=bool)
    for start in range(0, k, block_rows):
        sl = np.arange(start, min(k, start + block_rows))
        sl = sl[~invalid[sl]]
        if sl.size:
            out.put(sl, robust_solve(net.problem.with_frames(z[sl], observed[sl]), options,
                                     config.robust))
        if bar is not None:
            bar.update(min(k, start + block_rows) - start)
    if invalid.any():
        out.flag(invalid, Status.NON_FINITE,
                 "a measurement is out of range (range <= 0, |omega| > pi or not finite)")
    return out


def _check_motion(out: FusedRows, frame, z, obs, net, config, decide=None) -> None:
    """The motion check (its hypotheses fitted by ``config.solve``'s solver)."""
    options = _laplace(config)

    def refit(rows, mask, x0):
        problem = net.problem.with_frames(z[rows], mask)
        return solve(problem.with_initial_state(x0), options)

    apply_motion_check(out, frame, obs, obs & valid_rows(z), frame_period_s=net.frame_period_s,
                       refit=refit, node_names=net.node_names,
                       residual_gate_probability=RESIDUAL_GATE_PROBABILITY, decide=decide)


def _check_coverage(out: FusedRows, frame, z, obs, net, check: CoverageCheck,
                    reach_m, decide=None) -> None:
    given = dict(check.reach_m or {})
    if reach_m is None and len(given) < len(net.node_names):
        reach = None  # the farthest of the rows' own ranges
    else:
        reach = np.array([given[n] if n in given else reach_m[i]
                          for i, n in enumerate(net.node_names)], dtype=float)
    flag, node = uncovered_rows(frame, out.state, out.status == Status.OK, obs, z[:, :, 0],
                                net.poses, frame_period_s=net.frame_period_s,
                                body_m=DEFAULT_BODY_M, reach_m=reach, decide=decide)
    for r in np.flatnonzero(flag):
        out.flag(r, Status.MOTION_INCONSISTENT,
                 f"motion check: node {net.node_names[node[r]]} covers this place and "
                 "does not see the target in the frames around (a multipath image or a ghost)",
                 rejected=obs[r])


def check_rows(out: FusedRows, frame: NDArray, detection_index: NDArray, z: NDArray,
               net: FusionNetwork, config: FusionConfig, *, reach_m=None,
               decide: NDArray | None = None) -> None:
    """The checks on the solved rows, in place: the motion check
    (docs/ROBUST.md), then the one-node rows of frames the association split
    (after the motion check, the only row of a frame it kept stays), then the
    coverage check, then the placement check (:class:`UnplacedCheck`). ``frame`` (K,) sorted, ``detection_index`` (K, N), ``z``
    (K, N, 3): the groups of the rows; ``reach_m`` (N,): each node's reach
    where the coverage check gives none (None: the farthest of the rows'
    ranges); ``decide``: the frames whose rows the motion and coverage checks
    decide (None: all; the others are context)."""
    obs = detection_index >= 0
    solved = out.status == Status.OK            # before the checks (the placement check's links)
    motion = config.check(MotionCheck) is not None
    if motion:
        _check_motion(out, frame, z, obs, net, config, decide)
    if config.check(SplitCheck) is not None:
        split = split_rows(frame, detection_index, out.status, keep_sole=motion)
        # The estimate and its covariance stay for whoever wants them, untrusted.
        out.flag(split, Status.RESIDUAL_TEST_FAILED, SPLIT_MESSAGE, keep_covariance=True)
    coverage = config.check(CoverageCheck)
    if coverage is not None:
        _check_coverage(out, frame, z, obs, net, coverage, reach_m, decide)
    if config.check(UnplacedCheck) is not None:
        check_placement(out, frame, obs, net, decide, solved)


def check_placement(out: FusedRows, frame, obs, net: FusionNetwork, decide, solved) -> None:
    """The placement check of :func:`check_rows` alone (the stream runs it on
    its look-back, the other checks on their context): ``obs`` (K, N) the
    nodes grouped, ``solved`` (K,) the rows the solve fused (before the checks)."""
    kept = obs & ~out.rejected
    flag = unplaced_rows(frame, out.state[:, :2], out.status == Status.OK, kept,
                         frame_period_s=net.frame_period_s, body_m=DEFAULT_BODY_M,
                         decide=decide, solved=solved, seen=obs)
    for r in np.flatnonzero(flag):
        node = net.node_names[int(np.argmax(kept[r]))]
        out.flag(r, Status.MOTION_INCONSISTENT, UNPLACED_MESSAGE.format(node=node))


def grid_covariances(out: FusedRows, z, kept, net, config, progress) -> NDArray:
    """The grid covariance of every converged row of the measurements
    ``kept`` (K, N) (a failure flags the row); the Laplace one elsewhere."""
    chosen = out.covariance.copy()
    rows = np.flatnonzero(out.status == Status.OK)
    with progress_bar(rows.size, "grid covariance", progress) as bar:
        for i in rows:
            try:
                grid = grid_posterior(out.state[i], net.poses, z[i], observed=kept[i],
                                      noise=net.noise[0], prior=config.prior,
                                      scale_covariance=out.covariance[i],
                                      points_per_axis=config.solve.grid_points_per_axis)
                chosen[i] = grid.covariance
                if grid.message:
                    out.message[i] = f"{out.message[i]}; {grid.message}"
            except MmsnapError as exc:
                chosen[i] = np.nan
                out.flag(i, Status.GRID_FAILED, f"grid covariance failed: {exc}",
                         keep_covariance=True)
            bar.update(1)
    return chosen


def fused_sequence(frame, target, label, detection_index, out: FusedRows, chosen,
                   net: FusionNetwork, config: FusionConfig, *,
                   time_origin_s: float | None = None) -> FusedSequence:
    """The :class:`FusedSequence` of the rows ``out`` of the groups
    ``frame``, ``target``, ``label``, ``detection_index`` (K, N)."""
    noise = net.noise
    prior = config.prior
    return FusedSequence(
        node_names=tuple(net.node_names), node_poses=net.poses, mode=config.mode,
        covariance_method=config.solve.covariance, solver=config.solve.solver,
        frame=frame, target=target, label=label, detection_index=detection_index,
        observed=detection_index >= 0, state=out.state, covariance=chosen,
        laplace_covariance=out.covariance, success=out.status == Status.OK, status=out.status,
        message=out.message, iterations=out.iterations, final_cost=out.final_cost,
        degeneracy=out.degeneracy,
        # (3,) for one noise, (N, 3) (node order) for per-node noise.
        noise_sigmas=(np.asarray(noise[0].sigmas, dtype=float)
                      if noise.count(noise[0]) == len(noise) else node_sigmas(noise)),
        prior_mean=None if prior is None else np.asarray(prior.mean, dtype=float),
        prior_sigmas=None if prior is None else np.asarray(prior.sigmas, dtype=float),
        gate_probability=config.association.gate_probability, rejected=out.rejected,
        robust=None if config.robust is None else config.robust.kernel,
        frame_period_s=net.frame_period_s, time_origin_s=time_origin_s)


def screen_rows(fused: FusedSequence, config: FusionConfig, *, walls=None
                ) -> tuple[FusedSequence, RoomReport]:
    """The checks in the reference frame (:func:`~.room.screen_room`): the
    room's (:class:`RoomCheck`), the learned walls (:class:`LearnedWalls`;
    learned from ``fused`` itself, or the walls given) and the duplicates
    (:class:`DuplicateCheck`)."""
    room = config.check(RoomCheck)
    dup = config.check(DuplicateCheck)
    return screen_room(
        fused, bounds=None if room is None else room.bounds,
        static_bounds=None if room is None else room.static_bounds,
        in_front=False if room is None else room.in_front,
        walls=config.check(LearnedWalls) is not None, learned=walls,
        body_m=None if dup is None else dup.body_m)


def fuse_rows(frame, target, label, detection_index, z, net: FusionNetwork,
              config: FusionConfig, *, progress: bool | None = None,
              time_origin_s: float | None = None) -> FusedSequence:
    """Solve and check K groups, and their grid covariance (stages 1-3 of the
    module docstring): the rows before :func:`screen_rows`."""
    obs = detection_index >= 0
    with progress_bar(z.shape[0], f"fuse ({config.solve.solver}, {config.mode})",
                      progress) as bar:
        out = solve_groups(z, obs, net, config, bar=bar)
    check_rows(out, frame, detection_index, z, net, config)
    chosen = out.covariance.copy()
    if config.solve.covariance == "grid":  # the grid posterior of the measurements kept
        gate = config.robust is not None and config.robust.kernel == "gate"
        kept = obs & ~out.rejected if (gate or config.check(MotionCheck)) else obs
        chosen = grid_covariances(out, z, kept, net, config, progress)
    return fused_sequence(frame, target, label, detection_index, out, chosen, net, config,
                          time_origin_s=time_origin_s)


def run_pipeline(frame, target, label, detection_index, z, net: FusionNetwork,
                 config: FusionConfig, *, progress: bool | None = None,
                 time_origin_s: float | None = None) -> tuple[FusedSequence, RoomReport]:
    """Every stage on K groups (:func:`fuse_rows`, then :func:`screen_rows`)."""
    return screen_rows(fuse_rows(frame, target, label, detection_index, z, net, config,
                                 progress=progress, time_origin_s=time_origin_s), config)
