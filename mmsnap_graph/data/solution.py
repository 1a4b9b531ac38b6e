"""The one record of a one-shot solve: :class:`FusionSolution`.

Every solver of :func:`mmsnap_graph.fusion.solve.solve` (``"gtsam"``,
``"vectorized"``, ``"scalar"``) and the robust wrapper
:func:`mmsnap_graph.fusion.solve.robust_solve` return it, for the ``F`` frames of
a :class:`~mmsnap_graph.fusion.frame_problem.FrameProblem`. One field set, one
shape convention (a leading frame axis, also for a single frame) and a status
code per frame whose message comes from the one table of
:class:`~mmsnap_graph.data.results.Status` (as scipy's ``OptimizeResult``
carries ``status`` and ``message``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import ValidationError
from .results import DEGENERACY_THRESHOLD, Status

__all__ = ["FusionSolution", "status_messages"]

#: Each status code's message, indexed by the code (the one table).
_MESSAGES = np.array([Status(c).message for c in range(max(Status) + 1)], dtype=object)


def status_messages(status: ArrayLike) -> NDArray:
    """Each :class:`~mmsnap_graph.data.results.Status` code's message (the
    one table), as an object array of the codes' shape."""
    return _MESSAGES[np.asarray(status, dtype=np.int64)]


def _frozen(value, dtype, shape, name) -> NDArray:
    arr = np.asarray(value, dtype=dtype)
    if arr.shape != shape:
        raise ValidationError(f"FusionSolution.{name} must have shape {shape}, got {arr.shape}")
    if arr.flags.writeable:
        if not arr.flags.owndata:
            arr = arr.copy()
        arr.setflags(write=False)
    return arr


@dataclass(frozen=True, kw_only=True, slots=True, eq=False)
class FusionSolution:
    """The one-shot estimates of ``F`` frames of ``N`` nodes.

    state : (F, 4) float
        MAP (or ML) ``(x_m, y_m, vx_mps, vy_mps)`` in the global frame; the
        last iterate where the frame failed (NaN when it did not start).
    covariance : (F, 4, 4) float
        The Laplace covariance (the inverse Gauss-Newton information at
        ``state``, what ``gtsam.Marginals`` gives; with uncertain node poses,
        theirs included); NaN where ``status`` is not OK.
    status : (F,) int8
        :class:`~mmsnap_graph.data.results.Status` codes; ``success`` and
        ``message`` follow from it.
    iterations : (F,) int
        Levenberg-Marquardt iterations (the vectorized solver counts steps).
    final_cost : (F,) float
        GTSAM's graph error at ``state``: half the sum of squared whitened
        residuals (a robust kernel's loss instead), prior included.
    initial_state : (F, 4) float
        Where the optimizer started.
    whitened_residuals : (F, N, 3) float
        ``(h(state) - z) / sigma`` per node (spatial frequency wrapped); NaN
        rows for nodes that did not observe the target.
    degeneracy : (F,) float
        Condition number (>= 1, ``inf`` for parallel lines of sight or one
        node) of the lines of sight's velocity information at ``state``
        (:data:`~mmsnap_graph.data.results.DEGENERACY_THRESHOLD`).
    rejected : (F, N) bool
        Nodes the robust fit left out (the residual gate) or down-weighted
        (a kernel: the residual fails the gate); all False without one.
    grid_covariance : (F, 4, 4) float or None
        The paper's grid posterior covariance (``covariance="grid"``) of the
        frames that succeeded; None otherwise.
    """

    state: NDArray
    covariance: NDArray
    status: NDArray
    iterations: NDArray
    final_cost: NDArray
    initial_state: NDArray
    whitened_residuals: NDArray
    degeneracy: NDArray
    rejected: NDArray | None = None
    grid_covariance: NDArray | None = None

    def __post_init__(self) -> None:
        state = np.asarray(self.state, dtype=float)
        if state.ndim != 2 or state.shape[1] != 4:
            raise ValidationError(f"FusionSolution.state must have shape (F, 4), got {state.shape}")
        f = state.shape[0]
        res = np.asarray(self.whitened_residuals, dtype=float)
        if res.ndim != 3 or res.shape[0] != f or res.shape[2] != 3:
            raise ValidationError(f"FusionSolution.whitened_residuals must have shape "
                                  f"({f}, N, 3), got {res.shape}")
        n = res.shape[1]
        fields = (("state", float, (f, 4)), ("covariance", float, (f, 4, 4)),
                  ("status", np.int8, (f,)), ("iterations", np.int64, (f,)),
                  ("final_cost", float, (f,)), ("initial_state", float, (f, 4)),
                  ("whitened_residuals", float, (f, n, 3)), ("degeneracy", float, (f,)))
        for name, dtype, shape in fields:
            object.__setattr__(self, name, _frozen(getattr(self, name), dtype, shape, name))
        rejected = np.zeros((f, n), dtype=bool) if self.rejected is None else self.rejected
        object.__setattr__(self, "rejected", _frozen(rejected, bool, (f, n), "rejected"))
        if self.grid_covariance is not None:
            object.__setattr__(self, "grid_covariance", _frozen(
                self.grid_covariance, float, (f, 4, 4), "grid_covariance"))

    @classmethod
    def of_solver(cls, *, state, covariance, status, iterations, final_cost, initial_state,
                  whitened_residuals, degeneracy) -> "FusionSolution":
        """The solution a solver assembled: arrays it owns, of the right
        shapes and dtypes (float, ``status`` int8, ``iterations`` int64),
        frozen here without the checks of the constructor (the per-frame
        path of the stream); nothing rejected, no grid covariance."""
        out = object.__new__(cls)
        set_ = object.__setattr__
        rejected = np.zeros(whitened_residuals.shape[:2], dtype=bool)
        for name, value in zip(_SOLVER_FIELDS, (state, covariance, status, iterations, final_cost,
                                                initial_state, whitened_residuals, degeneracy,
                                                rejected)):
            value.setflags(write=False)
            set_(out, name, value)
        set_(out, "grid_covariance", None)
        return out

    def __len__(self) -> int:
        return int(self.status.shape[0])

    @property
    def n_nodes(self) -> int:
        """N, the nodes of the problem."""
        return int(self.rejected.shape[1])

    @property
    def success(self) -> NDArray:
        """(F,) bool: ``status == Status.OK`` (a finite state and a
        positive-definite covariance)."""
        return self.status == Status.OK

    @property
    def message(self) -> NDArray:
        """(F,) str: each frame's status message, from the one table."""
        return status_messages(self.status)

    @property
    def degenerate(self) -> NDArray:
        """(F,) bool: ``degeneracy > DEGENERACY_THRESHOLD``."""
        return self.degeneracy > DEGENERACY_THRESHOLD

    def __getitem__(self, index) -> "FusionSolution":
        """The frames ``index`` (an int, a slice, indices or a mask) as a
        solution of their own; an int keeps the frame axis (one frame)."""
        if isinstance(index, (int, np.integer)):
            index = [int(index)]
        grid = None if self.grid_covariance is None else self.grid_covariance[index]
        return FusionSolution(
            state=self.state[index], covariance=self.covariance[index],
            status=self.status[index], iterations=self.iterations[index],
            final_cost=self.final_cost[index], initial_state=self.initial_state[index],
            whitened_residuals=self.whitened_residuals[index],
            degeneracy=self.degeneracy[index], rejected=self.rejected[index],
            grid_covariance=grid)


_SOLVER_FIELDS = ("state", "covariance", "status", "iterations", "final_cost", "initial_state",
                  "whitened_residuals", "degeneracy", "rejected")
