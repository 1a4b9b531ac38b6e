"""Test-only ROS bags of TI point clouds, written by ``rosbags``' own writers.

The clouds are encoded in the byte layouts of TI's ROS drivers (x@0, y@4,
z@8, intensity@16, velocity@20 float32, point_step 32; the radar-lab layout
without velocity) and in ROS axes (x = the sensor's boresight y, y = the
sensor's -x), so that a reader test starts from known sensor-frame points.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

#: name -> (offset, present in the radar-lab layout)
TI_FIELDS = {"x": (0, True), "y": (4, True), "z": (8, True), "intensity": (16, True),
             "velocity": (20, False)}
POINT_STEP = 32
MSGTYPE = "sensor_msgs/msg/PointCloud2"


def cloud_bytes(xyz_sensor, doppler, snr_db, *, velocity: bool = True) -> tuple[bytes, list]:
    """Points in TI's sensor frame -> (the PointCloud2 data bytes in ROS
    axes, the field list [(name, offset)])."""
    xyz = np.asarray(xyz_sensor, dtype=float).reshape(-1, 3)
    names = [n for n, (_, lab) in TI_FIELDS.items() if velocity or lab]
    dtype = np.dtype({"names": names, "formats": ["<f4"] * len(names),
                      "offsets": [TI_FIELDS[n][0] for n in names], "itemsize": POINT_STEP})
    rec = np.zeros(xyz.shape[0], dtype=dtype)
    rec["x"], rec["y"], rec["z"] = xyz[:, 1], -xyz[:, 0], xyz[:, 2]   # ROS axes
    rec["intensity"] = snr_db
    if velocity:
        rec["velocity"] = doppler
    return rec.tobytes(), [(n, TI_FIELDS[n][0]) for n in names]


def _message(typestore, ros: int, seq: int, stamp_ns: int, frame_id: str, data: bytes, fields,
             n: int):
    t = typestore.types
    time = t["builtin_interfaces/msg/Time"](sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9)
    header = (t["std_msgs/msg/Header"](seq=seq, stamp=time, frame_id=frame_id) if ros == 1
              else t["std_msgs/msg/Header"](stamp=time, frame_id=frame_id))
    pf = t["sensor_msgs/msg/PointField"]
    return t[MSGTYPE](header=header, height=1, width=n,
                      fields=[pf(name=name, offset=off, datatype=7, count=1)
                              for name, off in fields],
                      is_bigendian=False, point_step=POINT_STEP, row_step=POINT_STEP * n,
                      data=np.frombuffer(data, dtype=np.uint8), is_dense=True)


def write_bag(path, topics, *, ros: int, storage: str = "sqlite3", velocity: bool = True,
              zero_stamps: bool = False, frame_id: str = "ti_mmwave") -> Path:
    """Write ``topics`` = ``{topic: [(receive_ns, header_ns, xyz (K, 3), doppler (K,),
    snr (K,)), ...]}`` as a ROS 1 ``.bag`` (``ros=1``) or a ROS 2 bag folder
    (``storage`` ``"sqlite3"`` or ``"mcap"``). ``zero_stamps``: every
    ``header.stamp`` 0 and ``frame_id`` empty, as TI's driver writes them."""
    from rosbags.typesys import Stores, get_typestore

    path = Path(path)
    if ros == 1:
        from rosbags.rosbag1 import Writer
        typestore = get_typestore(Stores.ROS1_NOETIC)
        writer = Writer(path)
        serialize = typestore.serialize_ros1
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer
        typestore = get_typestore(Stores.ROS2_HUMBLE)
        plugin = {"sqlite3": StoragePlugin.SQLITE3, "mcap": StoragePlugin.MCAP}[storage]
        writer = Writer(path, version=9, storage_plugin=plugin)
        serialize = typestore.serialize_cdr
    with writer:
        conns = {topic: writer.add_connection(topic, MSGTYPE, typestore=typestore)
                 for topic in topics}
        messages = sorted((m[0], topic, i, m) for topic, ms in topics.items()
                          for i, m in enumerate(ms))
        for receive_ns, topic, seq, (_, header_ns, xyz, doppler, snr) in messages:
            data, fields = cloud_bytes(xyz, doppler, snr, velocity=velocity)
            msg = _message(typestore, ros, seq, 0 if zero_stamps else header_ns,
                           "" if zero_stamps else frame_id, data, fields, len(xyz))
            writer.write(conns[topic], receive_ns, serialize(msg, MSGTYPE))
    return path
