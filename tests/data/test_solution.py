"""The one record of a solve: one field set, read-only arrays, a frame axis
always, success and message derived from the status (the one table)."""

from __future__ import annotations

import numpy as np
import pytest

from mmsnap_graph.data.results import Status
from mmsnap_graph.data.solution import FusionSolution, status_messages
from mmsnap_graph.errors import ValidationError


def _solution(f=3, n=2):
    return FusionSolution(state=np.zeros((f, 4)), covariance=np.tile(np.eye(4), (f, 1, 1)),
                          status=np.array([0, 2, 9][:f]), iterations=np.arange(f),
                          final_cost=np.ones(f), initial_state=np.zeros((f, 4)),
                          whitened_residuals=np.zeros((f, n, 3)), degeneracy=[1.0, 200.0, 5.0][:f])


def test_fields_derive_from_the_status_table():
    sol = _solution()
    assert sol.success.tolist() == [True, False, False]
    assert sol.message.tolist() == [Status(0).message, Status(2).message, Status(9).message]
    assert status_messages([[0, 4]]).shape == (1, 2)
    assert sol.degenerate.tolist() == [False, True, False]
    assert sol.rejected.shape == (3, 2) and not sol.rejected.any()
    assert sol.status.dtype == np.int8 and sol.n_nodes == 2
    for name in ("state", "covariance", "status", "rejected", "whitened_residuals"):
        assert not getattr(sol, name).flags.writeable, name


def test_indexing_keeps_the_frame_axis():
    sol = _solution()
    one = sol[1]
    assert len(one) == 1 and one.state.shape == (1, 4) and one.status.tolist() == [2]
    assert len(sol[sol.success]) == 1 and len(sol[1:]) == 2


def test_shapes_are_checked():
    with pytest.raises(ValidationError, match=r"covariance must have shape \(3, 4, 4\)"):
        FusionSolution(state=np.zeros((3, 4)), covariance=np.zeros((3, 4)),
                       status=np.zeros(3), iterations=np.zeros(3), final_cost=np.zeros(3),
                       initial_state=np.zeros((3, 4)), whitened_residuals=np.zeros((3, 2, 3)),
                       degeneracy=np.zeros(3))
