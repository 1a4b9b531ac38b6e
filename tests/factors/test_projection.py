"""3D sensor-frame points -> the 2D measurement plane (factors.projection), checked
against the 2D models of factors.models for the same target."""

import numpy as np
import pytest

from factors.models import measurement_model
from factors.projection import (cartesian_to_spherical, level_to_sensor, project_to_plane,
                                room_to_sensor, sensor_to_level, sensor_to_room,
                                spherical_to_cartesian)
from mmsnap_graph.errors import ValidationError
from mmsnap_graph.io.ti.point_cloud import (Mounting, PointCloud3D, cloud_to_detections,
                                         recording_from_point_clouds)


def _rot(axis, angle):
    """Rotation matrix about a unit axis (Rodrigues), independent of the module."""
    k = np.asarray(axis, float)
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * kx + (1 - np.cos(angle)) * kx @ kx


def _scene(seed, n=200):
    """Random nodes (pose, height, tilt) and horizontally moving targets in a room."""
    rng = np.random.default_rng(seed)
    pose = np.array([rng.uniform(-2, 2), rng.uniform(-2, 2), rng.uniform(-np.pi, np.pi)])
    height, tilt = rng.uniform(0.8, 1.2), rng.uniform(0.0, 0.4)
    local = np.stack([rng.uniform(-4, 4, n), rng.uniform(0.5, 6, n)], axis=1)
    c, s = np.cos(pose[2]), np.sin(pose[2])
    pos = pose[:2] + local @ np.array([[c, s], [-s, c]])
    z = rng.uniform(0.2, 1.8, n)
    vel = rng.uniform(-1.5, 1.5, size=(n, 2))
    return pose, height, tilt, pos, z, vel


def _sensor_points(pose, height, tilt, pos, z, vel):
    """Sensor-frame points and radial speeds from explicit rotation matrices:
    sensor axes in the room = yaw(phi) @ tilt-down about the array axis."""
    r_yaw = _rot([0, 0, 1], pose[2])
    r_tilt = _rot([1, 0, 0], -tilt)                   # looking down = negative about x
    axes = r_yaw @ r_tilt                              # columns: sensor x, y, z in room
    d = np.column_stack([pos - pose[:2], z - height])
    xyz = d @ axes                                     # room -> sensor: axes^T d
    v3 = np.column_stack([vel, np.zeros(len(vel))])
    doppler = np.sum(v3 * d, axis=1) / np.linalg.norm(d, axis=1)
    return xyz, doppler


@pytest.mark.parametrize("seed", range(5))
def test_projection_matches_the_2d_model(seed):
    pose, height, tilt, pos, z, vel = _scene(seed)
    xyz, doppler = _sensor_points(pose, height, tilt, pos, z, vel)
    proj = project_to_plane(xyz, doppler, height_m=height, tilt_rad=tilt)
    state = np.column_stack([pos, vel])
    expected, _ = measurement_model(state, np.broadcast_to(pose, (len(pos), 3)))
    assert proj.keep.all()
    np.testing.assert_allclose(proj.range_m, expected[:, 0], atol=1e-12)
    np.testing.assert_allclose(proj.omega_rad, expected[:, 1], atol=1e-12)
    np.testing.assert_allclose(proj.doppler_mps, expected[:, 2], atol=1e-12)
    np.testing.assert_allclose(proj.height_m, z, atol=1e-12)


def test_room_frame_points_go_back_to_the_sensor_frame():
    pose, height, tilt, pos, z, vel = _scene(7)
    xyz, _ = _sensor_points(pose, height, tilt, pos, z, vel)
    room = np.column_stack([pos, z])
    np.testing.assert_allclose(room_to_sensor(room, pose, height, tilt), xyz, atol=1e-12)
    np.testing.assert_allclose(sensor_to_room(xyz, pose, height, tilt), room, atol=1e-12)
    np.testing.assert_allclose(level_to_sensor(sensor_to_level(xyz, tilt), tilt), xyz,
                               atol=1e-12)


def test_spherical_round_trip_and_ti_axes():
    rng = np.random.default_rng(2)
    r, az, el = rng.uniform(1, 5, 20), rng.uniform(-1.2, 1.2, 20), rng.uniform(-0.6, 0.6, 20)
    xyz = spherical_to_cartesian(r, az, el)
    np.testing.assert_allclose(np.stack(cartesian_to_spherical(xyz)), np.stack([r, az, el]),
                               atol=1e-12)
    # Boresight (az = el = 0) is +y; positive azimuth is +x.
    np.testing.assert_allclose(spherical_to_cartesian(2.0, 0.0, 0.0), [0, 2, 0], atol=1e-15)
    assert spherical_to_cartesian(1.0, 0.3, 0.0)[0] > 0


def test_height_band_and_vertical_points():
    xyz = np.array([[0.0, 2.0, -1.0], [0.0, 2.0, 0.0], [0.0, 2.0, 1.5], [0.0, 0.0, -1.0]])
    proj = project_to_plane(xyz, np.zeros(4), height_m=1.0, tilt_rad=0.0,
                            height_band_m=(0.2, 2.0))
    assert proj.keep.tolist() == [False, True, False, False]      # floor, ok, ceiling, below
    assert proj.range_m.shape == (4,)


def test_cloud_to_detections_and_recording():
    pose, height, tilt, pos, z, vel = _scene(4, n=30)
    xyz, doppler = _sensor_points(pose, height, tilt, pos, z, vel)
    frame = np.repeat(np.arange(10, 16), 5)
    cloud = PointCloud3D(frame=frame, x_m=xyz[:, 0], y_m=xyz[:, 1], z_m=xyz[:, 2],
                         doppler_mps=doppler, snr_db=np.full(30, 12.0))
    mount = Mounting(height_m=height, tilt_rad=tilt)
    det = cloud_to_detections(cloud, mount)
    expected, _ = measurement_model(np.column_stack([pos, vel]), pose)
    np.testing.assert_allclose(det.measurements, expected, atol=1e-12)
    room = np.column_stack([pos, z])
    room_cloud = PointCloud3D(frame=frame, x_m=room[:, 0], y_m=room[:, 1], z_m=room[:, 2],
                              doppler_mps=doppler)
    det2 = cloud_to_detections(room_cloud, Mounting(height_m=height, tilt_rad=tilt,
                                                    room_pose=tuple(pose)))
    np.testing.assert_allclose(det2.measurements, expected, atol=1e-12)
    rec = recording_from_point_clouds({"S1": cloud, "S2": room_cloud}, frame_period_s=0.05,
                                      mounting={"S1": mount, "S2": Mounting(
                                          height_m=height, tilt_rad=tilt,
                                          room_pose=tuple(pose))})
    assert rec.nodes["S1"].point_cloud.frame.min() == 0          # counted from the first frame
    assert rec.nodes["S1"].point_cloud.snr_db is not None
    assert rec.nodes["S2"].point_cloud.snr_db is None
    assert rec.metadata["frame_clock"] == "frame_numbers"


def test_time_stamps_set_a_common_frame_clock():
    one = PointCloud3D(frame=[0, 1], x_m=[0, 0], y_m=[2, 2], z_m=[0, 0], doppler_mps=[0, 0],
                       time_s=[100.00, 100.05])
    two = PointCloud3D(frame=[5, 6], x_m=[0, 0], y_m=[3, 3], z_m=[0, 0], doppler_mps=[0, 0],
                       time_s=[100.11, 100.149])
    rec = recording_from_point_clouds({"A": one, "B": two}, frame_period_s=0.05)
    assert rec.nodes["A"].point_cloud.frame.tolist() == [0, 1]
    assert rec.nodes["B"].point_cloud.frame.tolist() == [2, 3]


def test_bad_inputs():
    with pytest.raises(ValidationError, match="tilt_rad"):
        Mounting(tilt_rad=2.0)
    with pytest.raises(ValidationError, match="room_pose"):
        Mounting(room_pose=(1, 2))
    with pytest.raises(ValidationError, match=r"x_m must be finite; point 1 \(frame 4\)"):
        PointCloud3D(frame=[3, 4], x_m=[0, np.nan], y_m=[1, 1], z_m=[0, 0], doppler_mps=[0, 0])
    cloud = PointCloud3D(frame=[0], x_m=[0], y_m=[1], z_m=[0], doppler_mps=[0])
    with pytest.raises(ValidationError, match="height_band_m"):
        cloud_to_detections(cloud, height_band_m=(2, 1))


def _cloud(frames_points):
    frame = np.concatenate([[f] * len(p) for f, p in frames_points.items()]).astype(int)
    pts = np.concatenate([np.asarray(p, float).reshape(-1, 4) for p in frames_points.values()])
    return PointCloud3D(frame=frame, x_m=pts[:, 0], y_m=pts[:, 1], z_m=pts[:, 2],
                        doppler_mps=pts[:, 3], frames=sorted(frames_points))


def test_destack_keeps_each_point_where_it_first_appears():
    from mmsnap_graph.io.ti.point_cloud import destack_frames
    a, b, c, d = ([1, 2, 0, 0.1], [2, 3, 0, 0.2], [3, 4, 0, 0.3], [4, 5, 0, 0.4])
    stacked = _cloud({0: [a], 1: [b, a], 2: [c, b], 3: [c], 4: [d]})   # stacks of 2
    out = destack_frames(stacked)
    assert out.frame.tolist() == [0, 1, 2, 4]
    np.testing.assert_array_equal(out.x_m, [1, 2, 3, 4])
    assert out.frames.tolist() == [0, 1, 2, 3, 4]
    # A point repeated after an empty frame is new again (not a stack copy).
    assert destack_frames(_cloud({0: [a], 2: [a]})).frame.tolist() == [0, 2]


def test_accumulate_merges_the_last_k_frames():
    from mmsnap_graph.io.ti.point_cloud import accumulate_frames
    a, b, c = ([1, 2, 0, 0.1], [2, 3, 0, 0.2], [3, 4, 0, 0.3])
    out = accumulate_frames(_cloud({0: [a], 1: [b], 2: [c]}), 2)
    assert out.frame.tolist() == [0, 1, 1, 2, 2]
    np.testing.assert_array_equal(out.x_m, [1, 1, 2, 2, 3])
    one = _cloud({0: [a], 1: [b]})
    np.testing.assert_array_equal(accumulate_frames(one, 1).x_m, one.x_m)
    with pytest.raises(ValidationError, match="n_frames=0"):
        accumulate_frames(one, 0)


from hypothesis import given, settings, strategies as st  # noqa: E402

_finite = st.floats(-20, 20, allow_nan=False)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(_finite, _finite, _finite), min_size=1, max_size=5),
       st.tuples(_finite, _finite, st.floats(-4, 4)), st.floats(0, 3), st.floats(-1.5, 1.5))
def test_room_sensor_round_trip_property(points, pose, height, tilt):
    p = np.asarray(points, float)
    back = sensor_to_room(room_to_sensor(p, pose, height, tilt), pose, height, tilt)
    np.testing.assert_allclose(back, p, atol=1e-9)
    proj = project_to_plane(room_to_sensor(p, pose, height, tilt), np.ones(len(p)),
                            height_m=height, tilt_rad=tilt)
    # Horizontal range is the room-frame distance to the node, whatever the tilt.
    np.testing.assert_allclose(proj.range_m, np.hypot(p[:, 0] - pose[0], p[:, 1] - pose[1]),
                               atol=1e-9)
    np.testing.assert_allclose(proj.height_m, p[:, 2], atol=1e-9)
    assert np.all(np.abs(proj.omega_rad) <= np.pi)
