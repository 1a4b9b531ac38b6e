"""Calibrated poses against the nominal poses the user gave
(mmsnap_graph.evaluation.nominal).

The calibrated poses are the real recording's (data/real/darksz, multiple
tracking: ``mmsnap import table ... --room-pose S1=0,0,0 --room-pose
S2=1.7,1.65,90``, ``process``, ``calibrate``): S2 at (1.738, 1.624) m, 86.24
deg; imported without S2's room pose, at (0.245, 0.178) m, 5.46 deg."""

from __future__ import annotations

import numpy as np
import pytest

from mmsnap_graph.errors import ValidationError
from mmsnap_graph.evaluation.nominal import (NominalPose, coincident_nodes, nominal_metadata,
                                             nominal_poses, pose_departures)

REAL_S2 = np.array([1.738, 1.624, np.deg2rad(86.24)])
REAL_S2_WITHOUT_ROOM_POSE = np.array([0.245, 0.178, np.deg2rad(5.46)])
ORIGIN = np.zeros(3)


def _nominal(s2_deg, s2_xy=(1.7, 1.65), s1=(0.0, 0.0, 0.0), source="pose"):
    md = {**nominal_metadata("S1", [s1[0], s1[1], np.deg2rad(s1[2])], source),
          **nominal_metadata("S2", [*s2_xy, np.deg2rad(s2_deg)], source)}
    return nominal_poses(md)


def test_nominal_poses_round_trip_through_the_metadata():
    md = nominal_metadata("S2", [1.7, 1.65, np.pi / 2], "room_pose")
    assert md == {"S2_nominal_x_m": 1.7, "S2_nominal_y_m": 1.65,
                  "S2_nominal_phi_rad": np.pi / 2, "S2_nominal_source": "room_pose"}
    (got,) = nominal_poses({**md, "S3_nominal_x_m": 1.0, "other": 3}).values()
    np.testing.assert_array_equal(got.pose, [1.7, 1.65, np.pi / 2])
    assert got.source == "room_pose"
    with pytest.raises(ValidationError, match="source='tape' must be one of"):
        NominalPose(pose=[0, 0, 0], source="tape")
    with pytest.raises(ValidationError, match="3 finite numbers"):
        nominal_metadata("S2", [0, np.nan, 0], "pose")


def test_a_pose_near_its_nominal_pose_is_not_reported():
    """The real recording's S2 lies 0.046 m and -3.8 deg from the tape."""
    poses = {"S1": ORIGIN, "S2": REAL_S2}
    assert pose_departures(poses, _nominal(90), reference="S1") == []
    assert coincident_nodes(poses) == []
    # Just inside and just beyond the limits (1 m, 45 deg).
    assert pose_departures({"S2": [2.65, 1.65, np.pi / 2]}, _nominal(90), reference="S1") == []
    assert len(pose_departures({"S2": [2.75, 1.65, np.pi / 2]}, _nominal(90),
                               reference="S1")) == 1
    assert len(pose_departures({"S2": [1.7, 1.65, np.deg2rad(136)]}, _nominal(90),
                               reference="S1")) == 1


@pytest.mark.parametrize("nominal, calibrated, cause", [
    (_nominal(180), REAL_S2, "boresight"),               # the boresight's heading given
    (_nominal(0), REAL_S2, "boresight"),
    (_nominal(-90), REAL_S2, "reversed"),
    (_nominal(1.5708), REAL_S2, "radians"),              # 90 deg typed as radians
    (_nominal(90), REAL_S2_WITHOUT_ROOM_POSE, "room_frame"),
    (_nominal(90, s2_xy=(4.0, 1.65)), REAL_S2, "unknown"),
])
def test_a_pose_far_from_its_nominal_pose_names_the_likely_cause(nominal, calibrated, cause):
    (d,) = pose_departures({"S1": ORIGIN, "S2": calibrated}, nominal, reference="S1")
    assert (d.node, d.cause, d.source) == ("S2", cause, "pose")
    expected = nominal["S2"].pose
    assert d.distance_m == pytest.approx(np.hypot(*(calibrated[:2] - expected[:2])))


def test_nominal_poses_are_taken_to_the_references_frame():
    """A room whose origin is not S1: S1 at (1, 2) heading 90 deg, S2 the real
    recording's S2 in that room (90 + 90 = 180 deg)."""
    s1 = np.array([1.0, 2.0, np.pi / 2])
    c, s = np.cos(s1[2]), np.sin(s1[2])
    x, y = s1[0] + c * 1.7 - s * 1.65, s1[1] + s * 1.7 + c * 1.65
    nominal = _nominal(180, s2_xy=(x, y), s1=(1.0, 2.0, 90.0), source="room_pose")
    assert pose_departures({"S1": ORIGIN, "S2": REAL_S2}, nominal, reference="S1") == []
    # Without the reference's nominal pose nothing is compared.
    assert pose_departures({"S2": [9, 9, 0]}, {"S2": nominal["S2"]}, reference="S1") == []


def test_two_nodes_calibrated_at_one_place():
    poses = {"S1": ORIGIN, "S2": REAL_S2_WITHOUT_ROOM_POSE, "S3": REAL_S2}
    (c,) = coincident_nodes(poses)
    assert (c.node_a, c.node_b) == ("S1", "S2")
    assert c.distance_m == pytest.approx(0.303, abs=1e-3)
    assert np.degrees(c.heading_difference_rad) == pytest.approx(5.46)
    assert coincident_nodes({"S1": ORIGIN, "S2": [0.3, 0.0, np.pi]}) == []   # back to back
