"""ROS bags of TI point clouds (mmsnap_graph.io.ti.rosbag), on bags written by
``rosbags``' own writers (tests/_rosbags.py) from simulated clouds."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

pytest.importorskip("rosbags")

from mmsnap_graph.errors import FileFormatError, ValidationError  # noqa: E402
from mmsnap_graph.io.ti.rosbag import cloud_fields, read_rosbag, ros_to_sensor  # noqa: E402

from _rosbags import write_bag  # noqa: E402
from ti_samples import MOUNTS, lift, simulated  # noqa: E402

T0_NS = 1_700_000_000 * 10**9   # receive times: Unix nanoseconds
HEADER0_NS = 5 * 10**9          # header stamps: another clock
PERIOD_NS = 50_000_000
TOPICS = {"/ti_mmwave/radar_scan_pcl_0": "S1", "/ti_mmwave/radar_scan_pcl_1": "S2"}
KINDS = [(1, "bag"), (2, "sqlite3"), (2, "mcap")]


@pytest.fixture(scope="module")
def clouds():
    """Per node: (frames, sensor xyz, doppler, snr) of a simulated walk (40 frames)."""
    rec = simulated(n_frames=40)
    out = {}
    for seed, name in enumerate(rec.node_names):
        det = rec.nodes[name].point_cloud
        xyz, dop = lift(det, *MOUNTS[name], seed)
        out[name] = (det.frame, xyz, dop, det.snr_db)
    return out


def _messages(clouds, lag_ns=0):
    """Bag messages per topic; S2's clouds arrive ``lag_ns`` after S1's."""
    out = {}
    for k, (topic, node) in enumerate(TOPICS.items()):
        frames, xyz, dop, snr = clouds[node]
        out[topic] = [(T0_NS + int(f) * PERIOD_NS + k * lag_ns, HEADER0_NS + int(f) * PERIOD_NS,
                       xyz[frames == f], dop[frames == f], snr[frames == f])
                      for f in np.unique(frames)]
    return out


def _bag(tmp_path, clouds, ros, storage, **kw):
    name = "walk.bag" if ros == 1 else f"walk_{storage}"
    return write_bag(tmp_path / name, _messages(clouds), ros=ros, storage=storage, **kw)


@pytest.mark.parametrize("ros, storage", KINDS)
@pytest.mark.parametrize("velocity", [True, False], ids=["ti-driver", "radar-lab"])
def test_clouds_come_back_in_the_sensor_frame(tmp_path, clouds, ros, storage, velocity):
    path = _bag(tmp_path, clouds, ros, storage, velocity=velocity)
    bag = read_rosbag(path, TOPICS)
    assert (bag.ros_version, bag.storage) == (ros, storage)
    assert bag.stamps == "header" and [t.node for t in bag.topics] == ["S1", "S2"]
    for t in bag.topics:
        frames, xyz, dop, snr = clouds[t.node]
        got = bag.clouds[t.node]
        assert t.velocity is velocity and t.zero_stamps == 0 and t.frame_ids == ("ti_mmwave",)
        assert t.messages == np.unique(frames).size and t.points == len(frames)
        np.testing.assert_array_equal(got.frame, np.searchsorted(np.unique(frames), frames))
        np.testing.assert_allclose(got.points_xyz, xyz, rtol=1e-6, atol=1e-6)  # float32
        np.testing.assert_allclose(got.doppler_mps, dop if velocity else 0.0, rtol=1e-6,
                                   atol=1e-6)
        np.testing.assert_allclose(got.snr_db, snr, rtol=1e-6)
        np.testing.assert_allclose(got.time_s, (HEADER0_NS + frames * PERIOD_NS) / 1e9,
                                   rtol=0, atol=1e-9)
        assert t.median_interval_s == pytest.approx(0.05)


@pytest.mark.parametrize("ros, storage", KINDS)
def test_zero_header_stamps_fall_back_to_the_receive_time(tmp_path, clouds, ros, storage):
    """TI's driver: header.stamp 0 and an empty frame_id in every cloud."""
    path = _bag(tmp_path, clouds, ros, storage, zero_stamps=True)
    bag = read_rosbag(path, TOPICS)
    assert bag.stamps == "receive" and "header.stamp 0" in bag.stamps_reason
    for t in bag.topics:
        frames = clouds[t.node][0]
        assert t.zero_stamps == t.messages and t.frame_ids == ("",)
        np.testing.assert_allclose(bag.clouds[t.node].time_s, (T0_NS + frames * PERIOD_NS) / 1e9,
                                   rtol=0, atol=1e-6)
    with pytest.raises(ValidationError, match="clouds have header.stamp 0; use --stamps receive"):
        read_rosbag(path, TOPICS, stamps="header")
    (tmp_path / "h").mkdir()
    assert read_rosbag(_bag(tmp_path / "h", clouds, ros, storage), TOPICS,
                       stamps="receive").stamps == "receive"


def test_bad_bags_and_topics_are_named(tmp_path, clouds):
    path = _bag(tmp_path, clouds, 2, "sqlite3")
    with pytest.raises(ValidationError, match=r"--topic /nope: .* no such topic; its PointCloud2 "
                                              r"topics: \['/ti_mmwave/radar_scan_pcl_0'"):
        read_rosbag(path, {"/nope": "S1"})
    with pytest.raises(ValidationError, match="node S1 is named for 2 topics"):
        read_rosbag(path, dict.fromkeys(TOPICS, "S1"))
    with pytest.raises(ValidationError, match="at least one --topic"):
        read_rosbag(path, {})
    with pytest.raises(ValidationError, match="stamps='now'"):
        read_rosbag(path, TOPICS, stamps="now")
    db3 = next(path.glob("*.db3"))
    with pytest.raises(FileFormatError, match="give the folder"):
        read_rosbag(db3, TOPICS)
    (tmp_path / "x.txt").write_text("hello")
    with pytest.raises(FileFormatError, match="not a ROS bag"):
        read_rosbag(tmp_path / "x.txt", TOPICS)
    with pytest.raises(FileFormatError, match="does not exist"):
        read_rosbag(tmp_path / "missing.bag", TOPICS)
    broken = tmp_path / "broken.bag"
    broken.write_bytes(b"#ROSBAG V2.0\n" + b"\x00" * 64)
    with pytest.raises(FileFormatError, match="cannot read the bag"):
        read_rosbag(broken, TOPICS)


def _msg(names, formats, offsets, step, values, big=False):
    """A PointCloud2-like message with the fields given (any layout)."""
    order = ">" if big else "<"
    dtype = np.dtype({"names": names, "formats": [order + f for f in formats],
                      "offsets": offsets, "itemsize": step})
    rec = np.zeros(len(values[0]), dtype=dtype)
    for n, v in zip(names, values):
        rec[n] = v
    kinds = {"f4": 7, "f8": 8, "i2": 3}
    fields = [SimpleNamespace(name=n, offset=o, datatype=kinds[f], count=1)
              for n, f, o in zip(names, formats, offsets)]
    return SimpleNamespace(fields=fields, width=len(values[0]), height=1, point_step=step,
                           is_bigendian=big, data=np.frombuffer(rec.tobytes(), np.uint8))


def test_fields_are_read_by_name_in_any_layout():
    """Big-endian float64 at other offsets, an int16 intensity: read by the
    field list, not by TI's offsets."""
    x, y, z, v = [1.5, -2.0], [3.25, 4.0], [0.5, -0.25], [-0.7, 0.3]
    msg = _msg(["velocity", "z", "y", "x", "intensity"], ["f8", "f8", "f8", "f8", "i2"],
               [0, 8, 16, 24, 40], 48, [v, z, y, x, [12, 30]], big=True)
    f = cloud_fields(msg, "m")
    np.testing.assert_array_equal(f["x"], x)
    np.testing.assert_array_equal(f["velocity"], v)
    np.testing.assert_array_equal(f["intensity"], [12, 30])
    np.testing.assert_array_equal(ros_to_sensor(f["x"], f["y"], f["z"]),
                                  np.column_stack([-np.array(y), x, z]))


def test_a_cloud_without_x_or_with_short_data_is_a_format_error():
    msg = _msg(["y", "z"], ["f4", "f4"], [0, 4], 8, [[1.0], [2.0]])
    with pytest.raises(FileFormatError, match=r"no field 'x' \(fields: \['y', 'z'\]\)"):
        cloud_fields(msg, "m")
    msg = _msg(["x", "y", "z"], ["f4", "f4", "f4"], [0, 4, 8], 12, [[1.0], [2.0], [3.0]])
    msg.width = 2
    with pytest.raises(FileFormatError, match="2 points of point_step 12 need 24 bytes"):
        cloud_fields(msg, "m")
    msg = _msg(["x", "y", "z"], ["f4", "f4", "f4"], [0, 4, 8], 12, [[1.0], [2.0], [3.0]])
    msg.fields[2].offset = 10
    with pytest.raises(FileFormatError, match="field 'z' has datatype 7 at offset 10"):
        cloud_fields(msg, "m")
