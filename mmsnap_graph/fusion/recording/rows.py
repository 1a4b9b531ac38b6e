"""The fused rows of a recording while the pipeline builds them: one solve
per row (a target in a frame), stored from the one record of a solve
(:class:`~mmsnap_graph.data.solution.FusionSolution`, its field names) with
:meth:`FusedRows.put`, and each row's message (the checks say why they
changed a row). The recording's checks (:mod:`.motion_check`,
:mod:`.split_check`) change the rows only through :meth:`FusedRows.put` and
:meth:`FusedRows.flag`.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ...data.results import Status
from ...data.solution import FusionSolution, status_messages

__all__ = ["FusedRows", "status_messages"]


class FusedRows:
    """K fused rows of ``N`` nodes: ``state (K, 4)``, ``covariance (K, 4,
    4)`` (the Laplace covariance; NaN for a failed row), ``status (K,)``
    int8 :class:`~mmsnap_graph.data.results.Status` codes, ``message (K,)``
    str, ``iterations (K,)``, ``final_cost (K,)``, ``degeneracy (K,)`` and
    ``rejected (K, N)`` bool (nodes left out or down-weighted). A row starts
    unsolved: NaN state, ``Status.OK`` until a solver puts its result."""

    __slots__ = ("state", "covariance", "status", "message", "iterations", "final_cost",
                 "degeneracy", "rejected")

    def __init__(self, k: int, n_nodes: int) -> None:
        self.state = np.full((k, 4), np.nan)
        self.covariance = np.full((k, 4, 4), np.nan)
        self.status = np.zeros(k, dtype=np.int8)
        self.message = np.empty(k, dtype=object)
        self.iterations = np.zeros(k, dtype=np.int64)
        self.final_cost = np.full(k, np.nan)
        self.degeneracy = np.full(k, np.inf)
        self.rejected = np.zeros((k, n_nodes), dtype=bool)

    @classmethod
    def of(cls, solved: FusionSolution) -> "FusedRows":
        """The rows of a solve (each row a frame of it), their messages the
        statuses'."""
        out = cls.__new__(cls)
        out.state, out.covariance = np.array(solved.state), np.array(solved.covariance)
        out.status, out.iterations = np.array(solved.status), np.array(solved.iterations)
        out.final_cost, out.degeneracy = np.array(solved.final_cost), np.array(solved.degeneracy)
        out.rejected = np.array(solved.rejected)
        out.message = solved.message
        return out

    def __len__(self) -> int:
        return int(self.status.size)

    def put(self, rows: ArrayLike, solved: FusionSolution, *, rejected: ArrayLike | None = None,
            message: ArrayLike | str | None = None) -> None:
        """Store the solve of ``len(rows)`` frames at ``rows``. ``rejected``
        defaults to the solve's own; ``message`` to each status' message."""
        self.state[rows] = solved.state
        self.covariance[rows] = solved.covariance
        self.status[rows] = solved.status
        self.iterations[rows] = solved.iterations
        self.final_cost[rows] = solved.final_cost
        self.degeneracy[rows] = solved.degeneracy
        self.rejected[rows] = solved.rejected if rejected is None else rejected
        self.message[rows] = solved.message if message is None else message

    def flag(self, rows: ArrayLike, status: Status, message: ArrayLike | str, *,
             rejected: ArrayLike | None = None, keep_covariance: bool = False) -> None:
        """Mark ``rows`` failed with ``status`` and ``message``; their
        estimate stays, their covariance becomes NaN unless
        ``keep_covariance`` (the row's covariance is reported but not
        trusted), and ``rejected`` (when given) replaces their nodes left
        out."""
        self.status[rows] = status
        self.message[rows] = message
        if not keep_covariance:
            self.covariance[rows] = np.nan
        if rejected is not None:
            self.rejected[rows] = rejected

    def ok(self) -> NDArray:
        """(K,) bool: the rows with ``Status.OK``."""
        return self.status == Status.OK
