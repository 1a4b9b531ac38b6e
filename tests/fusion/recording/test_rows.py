"""The rows of a recording being fused: written through put and flag only."""

from __future__ import annotations

import numpy as np

from _fusion import solved
from mmsnap_graph.data.results import Status
from mmsnap_graph.fusion.recording.rows import FusedRows
from factors.models import predict_measurements
from _shared import POSES_B


def test_put_takes_any_solve_and_flag_keeps_the_estimate():
    z = np.stack([predict_measurements(np.array([0.5, 3.0 + 0.1 * k, 0.2, -0.1]), POSES_B)
                  for k in range(3)])
    res = solved(POSES_B, z, solver="vectorized")
    rows = FusedRows(4, 2)
    assert len(rows) == 4 and np.isnan(rows.state).all() and not rows.rejected.any()
    rows.put(np.arange(3), res)
    np.testing.assert_array_equal(rows.state[:3], res.state)
    np.testing.assert_array_equal(rows.covariance[:3], res.covariance)
    np.testing.assert_array_equal(rows.final_cost[:3], res.final_cost)
    assert list(rows.message[:3]) == ["converged"] * 3 and rows.ok()[:3].all()
    rows.flag(1, Status.MOTION_INCONSISTENT, "motion check: a ghost", rejected=[True, False])
    assert rows.status[1] == Status.MOTION_INCONSISTENT and np.isnan(rows.covariance[1]).all()
    np.testing.assert_array_equal(rows.state[1], res.state[1])  # the estimate stays
    assert rows.rejected[1].tolist() == [True, False]
    rows.flag([2], Status.RESIDUAL_TEST_FAILED, "split", keep_covariance=True)
    np.testing.assert_array_equal(rows.covariance[2], res.covariance[2])
    assert rows.message[2] == "split" and not rows.ok()[2]
