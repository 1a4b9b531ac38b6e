"""ROS bags of TI radar point clouds -> one :class:`~.point_cloud.PointCloud3D` per node.

Reads ``sensor_msgs/PointCloud2`` topics of ROS 1 bags (``.bag``) and ROS 2
bags (a folder with ``metadata.yaml``, sqlite3 or MCAP storage) with the
pure-Python ``rosbags`` reader (no ROS install; ``pip install
"mmsnap_graph[rosbag]"``). Each message of a topic is one radar frame.

The layouts of TI's ROS drivers (docs/how-to/rosbag.md):

- TI's mmWave ROS driver: ``x`` at byte 0, ``y`` 4, ``z`` 8, ``intensity`` 16,
  ``velocity`` 20, all float32, ``point_step`` 32;
- the older radar-lab driver: the same without ``velocity`` (PCL's
  ``PointXYZI``): the Doppler is unknown.

The fields are read by name from each message's field list (any offsets,
point step, byte order, float32 or float64). ``intensity`` is the demo's SNR
in dB (the drivers write the SNR's 0.1 dB steps divided by 10). The drivers
publish in ROS axes (x forward = the sensor's boresight y, y left = the
sensor's -x, z up): :func:`ros_to_sensor` undoes the swap, so the clouds are
in TI's sensor frame, as every other import's.

Time stamps: a cloud's ``header.stamp``, or the bag's receive time of the
message where the stamps are not usable: TI's driver leaves ``header.stamp``
at 0 (and ``frame_id`` empty) in every cloud. With ``stamps="auto"`` every
topic uses the header stamps when no cloud of any topic has a zero stamp,
else every topic uses the receive times (one clock for all nodes);
:attr:`RosbagClouds.stamps` says which, and why.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal, Mapping

import numpy as np
from numpy.typing import NDArray

from ...errors import FileFormatError, MmsnapError, ValidationError
from .point_cloud import PointCloud3D

__all__ = ["RosbagTopic", "RosbagClouds", "read_rosbag", "ros_to_sensor", "cloud_fields",
           "STAMP_CHOICES", "POINTCLOUD2_TYPES"]

#: ``stamps=`` choices of :func:`read_rosbag`.
STAMP_CHOICES = ("auto", "header", "receive")
#: The message types read (ROS 2 and ROS 1 names as ``rosbags`` spells them).
POINTCLOUD2_TYPES = ("sensor_msgs/msg/PointCloud2", "sensor_msgs/PointCloud2")

# PointField datatypes (sensor_msgs/PointField) -> numpy kinds.
_DATATYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}
_NEEDED = ("x", "y", "z")


@dataclass(frozen=True, kw_only=True, slots=True)
class RosbagTopic:
    """What was read of one topic: ``topic``, ``node`` (its name in the
    recording), ``messages`` and ``points`` read, ``velocity`` (whether the
    clouds carry a velocity field: False for the radar-lab layout, whose
    Doppler is set to 0), ``zero_stamps`` (clouds with ``header.stamp`` 0),
    ``frame_ids`` (the distinct ``header.frame_id`` values, ``''`` when empty),
    ``median_interval_s`` (the median step of the stamps chosen between
    consecutive clouds: the frame period; None with one cloud)."""

    topic: str
    node: str
    messages: int
    points: int
    velocity: bool
    zero_stamps: int
    frame_ids: tuple
    median_interval_s: float | None


@dataclass(frozen=True, kw_only=True, slots=True)
class RosbagClouds:
    """The clouds of :func:`read_rosbag`: ``clouds`` (node -> sensor-frame
    :class:`PointCloud3D`, ``time_s`` the stamps chosen, in seconds of the
    bag's clock), ``topics`` (one :class:`RosbagTopic` each, in the order
    asked), ``stamps`` (``"header"`` or ``"receive"``), ``stamps_reason``
    (why, in words), ``ros_version`` (1 or 2) and ``storage`` (``"bag"``,
    ``"sqlite3"`` or ``"mcap"``)."""

    clouds: dict
    topics: tuple
    stamps: str
    stamps_reason: str
    ros_version: int
    storage: str


def ros_to_sensor(x_ros: NDArray, y_ros: NDArray, z_ros: NDArray) -> NDArray:
    """ROS axes (x forward, y left, z up) -> TI's sensor frame ``(K, 3)``:
    ``x_sensor = -y_ros``, ``y_sensor = x_ros`` (the boresight), ``z = z``."""
    return np.column_stack([-np.asarray(y_ros, float), np.asarray(x_ros, float),
                            np.asarray(z_ros, float)])


def cloud_fields(msg, where: str) -> dict[str, NDArray]:
    """The named float fields of one ``PointCloud2`` message as arrays
    ``(K,)``: ``x, y, z`` (always), ``intensity`` and ``velocity`` when the
    message has them. ``where`` names the message in errors."""
    fields = {f.name: f for f in msg.fields}
    missing = [n for n in _NEEDED if n not in fields]
    if missing:
        raise FileFormatError(f"{where}: the point cloud has no field {missing[0]!r} (fields: "
                              f"{sorted(fields)}); a TI cloud has x, y, z[, intensity, velocity]")
    n = int(msg.width) * int(msg.height)
    step = int(msg.point_step)
    data = np.asarray(msg.data, dtype=np.uint8)
    if n and (step <= 0 or data.size < n * step):
        raise FileFormatError(f"{where}: {n} points of point_step {step} need {n * step} bytes, "
                              f"the message holds {data.size}")
    order = ">" if msg.is_bigendian else "<"
    out = {}
    for name in ("x", "y", "z", "intensity", "velocity"):
        f = fields.get(name)
        if f is None:
            continue
        kind = _DATATYPES.get(int(f.datatype))
        if kind is None or int(f.offset) + np.dtype(kind).itemsize > step:
            raise FileFormatError(f"{where}: field {name!r} has datatype {f.datatype} at offset "
                                  f"{f.offset} (point_step {step}); expected a number inside "
                                  "each point")
        dtype = np.dtype({"names": [name], "formats": [order + kind], "offsets": [int(f.offset)],
                          "itemsize": step})
        out[name] = np.frombuffer(data[:n * step].tobytes(), dtype=dtype)[name].astype(float)
    return out


def _reader():
    try:
        from rosbags.highlevel import AnyReader
    except ImportError as exc:
        raise MmsnapError('reading ROS bags needs rosbags: pip install "mmsnap_graph[rosbag]" '
                          f'(or pip install ".[rosbag]" from the repository) ({exc})') from None
    return AnyReader


def _bag_kind(path: Path) -> tuple[int, str]:
    """(ROS version, storage) of the bag at ``path`` (a ``.bag`` file or a
    ROS 2 bag folder), or :class:`FileFormatError`."""
    if path.is_file() and path.suffix == ".bag":
        return 1, "bag"
    if path.is_dir() and (path / "metadata.yaml").is_file():
        text = (path / "metadata.yaml").read_text(encoding="utf-8", errors="replace")
        return 2, "mcap" if "storage_identifier: mcap" in text else "sqlite3"
    if path.is_file() and path.suffix in (".db3", ".mcap"):
        raise FileFormatError(f"{path}: a ROS 2 bag is the folder holding this file and its "
                              f"metadata.yaml; give the folder {str(path.parent)!r}")
    raise FileFormatError(f"{path}: not a ROS bag (a ROS 1 .bag file, or a ROS 2 bag folder "
                          "with metadata.yaml)")


def _read_topics(reader, topics, path):
    """Per topic: lists of (receive_ns, header_ns, fields) and the frame ids."""
    by_topic = {}
    for topic in topics:
        conns = [c for c in reader.connections if c.topic == topic]
        if not conns:
            have = sorted({c.topic for c in reader.connections if c.msgtype in POINTCLOUD2_TYPES})
            raise ValidationError(f"--topic {topic}: {path} has no such topic; its PointCloud2 "
                                  f"topics: {have}")
        bad = [c.msgtype for c in conns if c.msgtype not in POINTCLOUD2_TYPES]
        if bad:
            raise ValidationError(f"--topic {topic}: its messages are {bad[0]}, not "
                                  "sensor_msgs/PointCloud2")
        by_topic[topic] = ([], set())
    wanted = [c for c in reader.connections if c.topic in by_topic]
    for conn, receive_ns, raw in reader.messages(connections=wanted):
        rows, frame_ids = by_topic[conn.topic]
        where = f"{path}: {conn.topic} message {len(rows)}"
        try:
            msg = reader.deserialize(raw, conn.msgtype)
        except Exception as exc:  # rosbags' serde errors have no common base
            raise FileFormatError(f"{where} cannot be decoded: {exc}") from exc
        stamp = msg.header.stamp
        rows.append((int(receive_ns), int(stamp.sec) * 10**9 + int(stamp.nanosec),
                     cloud_fields(msg, where)))
        frame_ids.add(str(msg.header.frame_id))
    return by_topic


def _choose_stamps(by_topic, stamps) -> tuple[str, str]:
    zero = sum(sum(1 for _, h, _ in rows if h == 0) for rows, _ in by_topic.values())
    total = sum(len(rows) for rows, _ in by_topic.values())
    if stamps == "header":
        if zero:
            raise ValidationError(f"--stamps header: {zero} of {total} clouds have header.stamp "
                                  "0; use --stamps receive (or auto)")
        return "header", "the clouds' header stamps (--stamps header)"
    if stamps == "receive":
        return "receive", "the bag's receive times (--stamps receive)"
    if zero:
        return "receive", (f"the bag's receive times: {zero} of {total} clouds have "
                           "header.stamp 0 (TI's driver does not stamp its clouds)")
    return "header", "the clouds' header stamps"


def read_rosbag(path, topics: Mapping[str, str], *,
                stamps: Literal["auto", "header", "receive"] = "auto") -> RosbagClouds:
    """Read the ``PointCloud2`` topics of a ROS bag (module docstring).

    path : a ROS 1 ``.bag`` file or a ROS 2 bag folder; topics : topic ->
    node name, in node order; stamps : :data:`STAMP_CHOICES`.
    """
    if stamps not in STAMP_CHOICES:
        raise ValidationError(f"stamps={stamps!r} must be one of {STAMP_CHOICES}")
    if not topics:
        raise ValidationError("give at least one --topic TOPIC=NODE")
    nodes = list(topics.values())
    twice = sorted({n for n in nodes if nodes.count(n) > 1})
    if twice:
        raise ValidationError(f"--topic: node {twice[0]} is named for {nodes.count(twice[0])} "
                              "topics; one topic per node")
    p = Path(path)
    if not p.exists():
        raise FileFormatError(f"{p} does not exist")
    version, storage = _bag_kind(p)
    AnyReader = _reader()
    try:
        with AnyReader([p]) as reader:
            by_topic = _read_topics(reader, list(topics), p)
    except MmsnapError:
        raise
    except Exception as exc:  # a damaged bag: rosbags raises its own reader errors
        raise FileFormatError(f"{p}: cannot read the bag: {type(exc).__name__}: {exc}") from exc
    empty = [t for t, (rows, _) in by_topic.items() if not rows]
    if empty:
        raise ValidationError(f"--topic {empty[0]}: {p} holds no message on this topic")
    kind, reason = _choose_stamps(by_topic, stamps)
    clouds, infos = {}, []
    for topic, node in topics.items():
        rows, frame_ids = by_topic[topic]
        clouds[node], velocity = _cloud(rows, kind)
        stamp_s = np.array([r if kind == "receive" else h for r, h, _ in rows]) / 1e9
        step = float(np.median(np.diff(stamp_s))) if len(rows) > 1 else None
        infos.append(RosbagTopic(topic=topic, node=node, messages=len(rows),
                                 points=len(clouds[node]), velocity=velocity,
                                 zero_stamps=sum(1 for _, h, _ in rows if h == 0),
                                 frame_ids=tuple(sorted(frame_ids)), median_interval_s=step))
    return RosbagClouds(clouds=clouds, topics=tuple(infos), stamps=kind, stamps_reason=reason,
                        ros_version=version, storage=storage)


def _cloud(rows, kind) -> tuple[PointCloud3D, bool]:
    """One topic's messages -> its cloud (frame = message index) and whether
    every message had a velocity field."""
    velocity = all("velocity" in f for _, _, f in rows)
    counts = np.array([f["x"].size for _, _, f in rows])
    stamp_ns = np.array([r if kind == "receive" else h for r, h, _ in rows], dtype=np.int64)
    cat = lambda name: np.concatenate([f[name] for _, _, f in rows])  # noqa: E731
    xyz = ros_to_sensor(cat("x"), cat("y"), cat("z"))
    doppler = cat("velocity") if velocity else np.zeros(xyz.shape[0])
    snr = cat("intensity") if all("intensity" in f for _, _, f in rows) else None
    frames = np.arange(len(rows), dtype=np.int64)
    time_s = stamp_ns / 1e9  # the bag's clock (Unix seconds for receive times)
    return PointCloud3D(frame=np.repeat(frames, counts), x_m=xyz[:, 0], y_m=xyz[:, 1],
                        z_m=xyz[:, 2], doppler_mps=doppler, snr_db=snr,
                        time_s=np.repeat(time_s, counts), frames=frames), velocity
