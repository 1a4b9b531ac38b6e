"""The fused rows of a recording while :func:`~.sequence.fuse_recording`
builds them: one solve per row (a target in a frame), whichever solver
solved it, with the field names of every solve
(:class:`~mmsnap_graph.fusion.solvers.settings.FrameSolve`). The solvers
fill them with :meth:`FusedRows.put`; the recording's checks
(:mod:`.motion_check`, :mod:`.split_check`) change them only through
:meth:`FusedRows.put` and :meth:`FusedRows.flag`.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ...data.results import Status
from ..solvers.settings import FrameSolve

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

    def __len__(self) -> int:
        return int(self.status.size)

    def put(self, rows: ArrayLike, solved: FrameSolve, *, rejected: ArrayLike | None = None,
            message: ArrayLike | str | None = None) -> None:
        """Store a solve at ``rows``: a :class:`FrameSolve` of one frame (one
        row) or of ``len(rows)`` frames (a :class:`BatchResult`, or one
        indexed by a mask). ``rejected`` defaults to the solve's own
        (``solved.rejected``, else none); ``message`` to each status'
        message."""
        self.state[rows] = solved.state
        self.covariance[rows] = solved.covariance
        self.status[rows] = solved.status
        self.iterations[rows] = solved.iterations
        self.final_cost[rows] = solved.final_cost
        self.degeneracy[rows] = solved.degeneracy
        if rejected is None:
            rejected = getattr(solved, "rejected", False)
        self.rejected[rows] = rejected
        if message is None:
            message = status_messages(solved.status)
        self.message[rows] = message

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


#: Each status code's message, indexed by the code.
_MESSAGES = np.array([Status(c).message for c in range(max(Status) + 1)], dtype=object)


def status_messages(status: ArrayLike) -> NDArray:
    """Each :class:`~mmsnap_graph.data.results.Status` code's message (the
    one table), as an object array of the codes' shape."""
    return _MESSAGES[np.asarray(status, dtype=np.int64)]
