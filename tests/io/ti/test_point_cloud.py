"""Mounting and point-cloud checks (mmsnap_graph.io.ti.point_cloud)."""

from __future__ import annotations

import numpy as np
import pytest

from mmsnap_graph.errors import ValidationError
from mmsnap_graph.io.ti.point_cloud import (Mounting, PointCloud3D, accumulate_frames,
                                            check_frame_period, stamp_unit_factor)


def test_a_height_in_centimetres_is_named():
    assert Mounting(height_m=11.5).height_m == 11.5
    with pytest.raises(ValidationError, match=r"height_m=80.0 lies beyond \+-12 m: the height "
                                              r"is in metres \(centimetres\? 80 cm is 0.8 m\)"):
        Mounting(height_m=80.0, tilt_rad=0.1)


def _cloud(frames, stamps):
    n = len(frames)
    return PointCloud3D(frame=frames, x_m=np.zeros(n), y_m=np.ones(n), z_m=np.zeros(n),
                        doppler_mps=np.zeros(n), time_s=stamps)


def test_frame_period_check():
    frames = np.repeat(np.arange(50), 3)
    good = _cloud(frames, 100.0 + 0.05 * frames)
    assert check_frame_period(good, 0.05) is None
    assert "advance 0.05 s per frame" in check_frame_period(good, 0.1)
    coarse = _cloud(frames, np.floor(100.0 + 0.05 * frames))
    assert "coarser than a frame" in check_frame_period(coarse, 0.05)


def test_accumulated_stamps_move_with_their_frame():
    frames = np.arange(5)
    cloud = accumulate_frames(_cloud(frames, 10.0 + 0.1 * frames), 2, frame_period_s=0.1)
    np.testing.assert_allclose(cloud.time_s - 10.0, 0.1 * cloud.frame)
    with pytest.raises(ValidationError, match="would make"):
        accumulate_frames(_cloud(frames, 10.0 + 0.1 * frames), 10 ** 8)


def test_stamps_in_milliseconds_without_frame_numbers_are_a_unit_error():
    """Frames numbered from stamps in ms read as s lie 1000 frames apart
    (a real table gave frames 0-643000 and processed to no centroid)."""
    frames = np.repeat(np.arange(50), 3)
    stamps_ms = 50.0 * frames                        # 20 fps, in milliseconds
    as_seconds = _cloud(np.round(stamps_ms / 0.05).astype(int), stamps_ms)
    assert stamp_unit_factor(as_seconds, 0.05) == 1e3
    problem = check_frame_period(as_seconds, 0.05)
    assert "a median 1000 frames" in problem and "a factor of 1000" in problem
    right = _cloud(frames, stamps_ms * 1e-3)
    assert stamp_unit_factor(right, 0.05) is None and check_frame_period(right, 0.05) is None
    # A frame column: the stamps advance 1000 periods per frame, or a thousandth.
    assert stamp_unit_factor(_cloud(frames, stamps_ms), 0.05) == 1e3
    assert stamp_unit_factor(_cloud(frames, stamps_ms * 1e-6), 0.05) == 1e-3
    # Stamps in s read as ms: one stamp per frame, all merged into frame 0.
    merged = _cloud(np.zeros(frames.size, int), stamps_ms * 1e-6)
    assert stamp_unit_factor(merged, 0.05) == 1e-3
    assert "a factor of 0.001" in check_frame_period(merged, 0.05)
    # A sparse but real log (a person every other frame) is no unit error.
    assert stamp_unit_factor(_cloud(2 * frames, 0.1 * frames), 0.05) is None


def _room_cloud(n=200, seed=0):
    """Points in front of a node at (2, 1) with heading 90 deg (boresight -x),
    in the room frame."""
    from factors.projection import sensor_to_room
    rng = np.random.default_rng(seed)
    r, az = rng.uniform(1, 4, n), np.deg2rad(rng.uniform(-55, 55, n))
    sensor = np.column_stack([r * np.sin(az), r * np.cos(az), rng.uniform(-0.3, 0.3, n)])
    room = sensor_to_room(sensor, (2.0, 1.0, np.pi / 2), 1.0, 0.0)
    return PointCloud3D(frame=np.arange(n) // 4, x_m=room[:, 0], y_m=room[:, 1], z_m=room[:, 2],
                        doppler_mps=np.zeros(n))


@pytest.mark.parametrize("heading_deg, words", [
    (180, r"heading 90 deg puts 100.0% in front"),
    (0, r"heading 90 deg puts 100.0% in front"),
    (1.5708, r"heading 90 deg \(the 1.571 given, read as radians\) puts 100.0% in front"),
])
def test_a_room_pose_that_puts_the_points_beside_the_radar_is_an_error(heading_deg, words):
    from mmsnap_graph.io.ti.point_cloud import recording_from_point_clouds
    cloud = _room_cloud()
    good = Mounting(height_m=1.0, room_pose=(2.0, 1.0, np.pi / 2))
    rec = recording_from_point_clouds({"S1": cloud}, frame_period_s=0.05, mounting=good)
    assert len(rec.nodes["S1"].point_cloud) == 200
    bad = Mounting(height_m=1.0, room_pose=(2.0, 1.0, np.deg2rad(heading_deg)))
    with pytest.raises(ValidationError, match=r"node S1: \d+% of its 200 points lie more than "
                                              r"75 deg from the boresight .* the heading is the "
                                              r"direction of the antenna array axis, the "
                                              r"boresight heading \+ 90 deg; " + words):
        recording_from_point_clouds({"S1": cloud}, frame_period_s=0.05, mounting=bad)


def test_a_room_pose_for_some_nodes_only_warns():
    from mmsnap_graph.errors import MmsnapWarning
    from mmsnap_graph.io.ti.point_cloud import recording_from_point_clouds
    cloud = _room_cloud()
    sensor = PointCloud3D(frame=cloud.frame, x_m=cloud.x_m * 0 + 0.1, y_m=cloud.y_m * 0 + 2.0,
                          z_m=cloud.z_m, doppler_mps=cloud.doppler_mps)
    mounts = {"S1": Mounting(height_m=1.0, room_pose=(2.0, 1.0, np.pi / 2)),
              "S2": Mounting(height_m=1.0)}
    with pytest.warns(MmsnapWarning, match=r"nodes \['S1'\] have a room pose, \['S2'\] not: "
                                           r".*a missing --room-pose\?"):
        recording_from_point_clouds({"S1": cloud, "S2": sensor}, frame_period_s=0.05,
                                    mounting=mounts)


def _points(frames_points, stamps=None):
    """A cloud from {frame: [(x, y, z, doppler), ...]} (rows in the order given)."""
    frame = np.concatenate([[f] * len(p) for f, p in frames_points.items()]).astype(int)
    pts = np.concatenate([np.asarray(p, float).reshape(-1, 4) for p in frames_points.values()])
    time = None if stamps is None else stamps * frame
    return PointCloud3D(frame=frame, x_m=pts[:, 0], y_m=pts[:, 1], z_m=pts[:, 2],
                        doppler_mps=pts[:, 3], time_s=time)


def _stacked(raw, depth):
    """Saved frame k: the raw frames k - depth + 1 .. k, oldest first."""
    return {k: [p for f in raw[k - depth + 1:k + 1] for p in f] for k in range(depth - 1, len(raw))}


def test_destack_keeps_a_static_point_that_repeats_in_new_frames():
    """A wall gives the same quantised point in many frames: each frame's
    own copy is its point, not a stack copy (the old rule dropped every
    point equal to one of the previous stack: 756 of S2's 4,828 points of the
    two-person recording of data/real/darksz)."""
    from mmsnap_graph.io.ti.point_cloud import destack_frames
    wall = (0.0, 3.0, 1.0, 0.0)
    raw = [[wall, (0.1 * k, 1.0, 1.0, 0.5)] if k % 3 else [wall] for k in range(12)]
    out = destack_frames(_points(_stacked(raw, 4), stamps=0.05), frame_period_s=0.05)
    # The first stack's three older frames come back with their numbers and times.
    assert out.frames.tolist() == list(range(12))
    want = [f for f, pts in enumerate(raw) for _ in pts]
    assert out.frame.tolist() == want
    np.testing.assert_array_equal(out.x_m, [p[0] for pts in raw for p in pts])
    np.testing.assert_allclose(out.time_s, 0.05 * np.asarray(want))


def test_destack_finds_the_stack_depth_and_either_order():
    from mmsnap_graph.io.ti.point_cloud import destack_frames
    rng = np.random.default_rng(3)
    raw = [[tuple(rng.normal(size=4)) for _ in range(int(rng.integers(0, 4)))] for _ in range(40)]
    for depth in (2, 10):
        stacks = _stacked(raw, depth)
        for newest_first in (False, True):
            given = {k: v[::-1] for k, v in stacks.items()} if newest_first else stacks
            out = destack_frames(_points(given))
            got = [sorted(map(tuple, np.column_stack([out.x_m, out.y_m, out.z_m,
                                                      out.doppler_mps])[out.frame == f]))
                   for f in range(len(raw))]
            assert got == [sorted(f) for f in raw], (depth, newest_first)
