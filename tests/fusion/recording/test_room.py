"""Room-frame checks of fused rows (mmsnap_graph.fusion.recording.room): room
bounds, static bounds, one target per body."""

from __future__ import annotations

import numpy as np
import pytest

from mmsnap_graph.data.results import Status
from mmsnap_graph.errors import ValidationError
from mmsnap_graph.fusion.recording.room import RoomBounds, screen_room

from _fused_rows import fused_rows


ROOM = RoomBounds(x_min=-2.0, x_max=1.6, y_min=0.0, y_max=3.6)


def test_rows_outside_the_room_are_flagged_and_counted():
    rows = fused_rows([0, 0, 1, 1], [[0.0, 1.0], [2.5, 2.0], [1.6, 3.6], [-2.1, 1.0]])
    out, report = screen_room(rows, bounds=ROOM, body_m=None)
    np.testing.assert_array_equal(out.success, [True, False, True, False])
    np.testing.assert_array_equal(out.status, [0, Status.OUTSIDE_BOUNDS, 0, Status.OUTSIDE_BOUNDS])
    assert "outside the room bounds (x -2..1.6 m" in out.message[1]
    assert (report.outside, report.duplicate) == (2, 0)
    assert np.all(rows.success)                               # the input is not changed


def test_static_bounds_flag_only_targets_standing_still_outside_them():
    inner = RoomBounds(x_min=-1.0, x_max=1.0, y_min=0.5, y_max=3.0)
    rows = fused_rows([0, 0, 0], [[-1.5, 1.0], [-1.5, 2.5], [0.0, 1.0]],
                      velocity=[[0.0, 0.05], [0.6, 0.0], [0.0, 0.0]])
    out, report = screen_room(rows, bounds=ROOM, static_bounds=inner, body_m=None)
    np.testing.assert_array_equal(out.success, [False, True, True])
    assert "still" in out.message[0] and report.outside == 1


def test_one_body_seen_twice_keeps_the_better_supported_row():
    # Frame 0: a two-node row and a one-node row 0.6 m away (one walker: the
    # one-node row is flagged); frame 1: two people 1.5 m apart (both kept);
    # frame 2: two two-node rows 0.3 m apart, the higher cost one flagged.
    rows = fused_rows([0, 0, 1, 1, 2, 2],
                      [[0.0, 2.0], [0.5, 2.3], [0.0, 2.0], [1.5, 2.0], [0.0, 2.0], [0.3, 2.0]],
                      nodes=[2, 1, 2, 2, 2, 2], cost=[1, 0, 0, 0, 5, 1])
    out, report = screen_room(rows)
    np.testing.assert_array_equal(out.success, [True, False, True, True, False, True])
    assert out.status[1] == Status.DUPLICATE and "one body" in out.message[1]
    assert report.duplicate == 2
    same, none = screen_room(rows, body_m=None)
    assert same is rows and none.duplicate == 0


def test_duplicate_gate_grows_with_the_rows_uncertainty():
    # 1.0 m apart: two people when both rows are known to 3 cm, one body when
    # the rows are known to 0.3 m only.
    sharp = fused_rows([0, 0], [[0.0, 2.0], [1.0, 2.0]], nodes=[2, 1], sigma_m=0.03)
    vague = fused_rows([0, 0], [[0.0, 2.0], [1.0, 2.0]], nodes=[2, 1], sigma_m=0.3)
    assert screen_room(sharp)[1].duplicate == 0
    assert screen_room(vague)[1].duplicate == 1


@pytest.mark.parametrize("box", [dict(x_min=1.0, x_max=0.0, y_min=0.0, y_max=1.0),
                                 dict(x_min=0.0, x_max=1.0, y_min=0.0, y_max=float("inf"))])
def test_bad_bounds_are_validation_errors(box):
    with pytest.raises(ValidationError, match="room bounds"):
        RoomBounds(**box)
    with pytest.raises(ValidationError, match="body_m"):
        screen_room(fused_rows([0], [[0, 1]]), body_m=0.0)


def test_rows_behind_a_wall_mounted_radar_are_outside_the_room():
    # S1 at the origin looking along +y, S2 at (1.7, 1.65) looking along -x:
    # the room is y > 0 and x < 1.7.
    rows = fused_rows([0, 0, 0, 0], [[0.0, 1.0], [2.5, 2.0], [0.0, -0.5], [1.69, 3.0]])
    out, report = screen_room(rows, in_front=True, body_m=None)
    np.testing.assert_array_equal(out.success, [True, False, False, True])
    assert out.message[1] == "behind node S2 (outside the room)"
    assert out.message[2] == "behind node S1 (outside the room)"
    assert report.outside == 2
    assert screen_room(rows, body_m=None)[1].outside == 0          # off by default
