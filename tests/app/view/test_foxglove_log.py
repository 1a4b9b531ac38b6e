"""The Foxglove view (mmsnap_graph.app.view.foxglove_log): the MCAP log read
back with the pure-Python ``mcap`` reader, its protobuf messages decoded from
the schemas the file itself carries (mcap-protobuf-support), and the live
WebSocket on loopback."""

from __future__ import annotations

import base64
import json
import math
import os
import socket
import struct
import time
from collections import defaultdict

import numpy as np
import pytest

pytest.importorskip("foxglove")
pytest.importorskip("mcap_protobuf")

from mmsnap_graph.app.live.driver import replayed_frame  # noqa: E402
from mmsnap_graph.app.live.sinks import person_rows  # noqa: E402
from mmsnap_graph.app.view.foxglove_log import FoxgloveView, ViewOptions  # noqa: E402
from mmsnap_graph.errors import FileFormatError, MmsnapError, ValidationError  # noqa: E402
from mmsnap_graph.fusion.stream.frame_stream import FrameStream, recording_frames  # noqa: E402
from mmsnap_graph.sim import SimulationOptions, simulate_recording  # noqa: E402

ORIGIN_S = 1_700_000_000.0


@pytest.fixture(scope="module")
def replay():
    """Two walkers before configuration B's radars, 60 frames, streamed:
    the LiveFrames a replay gives, and the poses."""
    rec = simulate_recording("B", "random", SimulationOptions(physics=None, n_targets=2,
                                                              known_poses=True),
                             levels=("centroids",), n_frames=60, seed=11)
    poses = np.array([rec.nodes[n].pose for n in rec.node_names])
    stream = FrameStream(rec.node_names, poses)
    frames = [replayed_frame(f, t, d, stream.push(t, d)) for f, t, d in recording_frames(rec)]
    return rec.node_names, poses, frames


@pytest.fixture(scope="module")
def log(replay, tmp_path_factory):
    """The MCAP log of the replay, read back: topic -> [(log_time, schema, message)]."""
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    names, poses, frames = replay
    path = tmp_path_factory.mktemp("view") / "walk.mcap"
    view = FoxgloveView(names, poses, ViewOptions(log_path=path, time_origin_s=ORIGIN_S))
    for f in frames:
        view.write(f)
    view.close()
    out, factory = defaultdict(list), DecoderFactory()
    with open(path, "rb") as fh:
        for schema, channel, message in make_reader(fh).iter_messages():
            if channel.message_encoding == "json":
                decoded = json.loads(message.data)
            else:  # protobuf, from the FileDescriptorSet the file holds
                decoded = factory.decoder_for(channel.message_encoding, schema)(message.data)
            out[channel.topic].append((message.log_time, schema.name, decoded))
    return dict(out)


def test_every_topic_with_its_schema(log, replay):
    names, _, frames = replay
    schemas = {topic: {s for _, s, _ in msgs} for topic, msgs in log.items()}
    assert schemas == {"/radars": {"foxglove.SceneUpdate"}, "/tf": {"foxglove.FrameTransforms"},
                       "/points/S1": {"foxglove.PointCloud"}, "/points/S2": {"foxglove.PointCloud"},
                       "/centroids": {"foxglove.SceneUpdate"}, "/people": {"foxglove.SceneUpdate"},
                       "/tracks": {"foxglove.SceneUpdate"}, "/persons": {"mmsnap.persons"}}
    assert len(log["/people"]) == len(frames)
    # Log times: the frames' times on the wall clock; the radars once a second.
    times = [t for t, _, _ in log["/people"]]
    np.testing.assert_allclose(np.array(times) / 1e9, [ORIGIN_S + f.time_s for f in frames],
                               rtol=0, atol=1e-6)
    span_s = frames[-1].time_s - frames[0].time_s
    assert len(log["/radars"]) == math.floor(span_s / 1.0 + 1e-9) + 1


def test_people_are_ellipses_arrows_and_ids_of_the_tracks(log, replay):
    _, _, frames = replay
    seen = 0
    for (_, _, msg), f in zip(log["/people"], frames):
        u = f.update
        assert len(msg.deletions) == 1 and msg.deletions[0].type == 1   # ALL: ended tracks go
        assert [e.id for e in msg.entities] == [f"person/{i}" for i in u.track_id]
        for e, x, p in zip(msg.entities, u.track_state, u.track_covariance):
            xy = np.array([[q.x, q.y] for q in e.lines[0].points])
            d = xy - x[:2]
            m2 = np.einsum("ki,ij,kj->k", d, np.linalg.inv(p[:2, :2]), d)
            np.testing.assert_allclose(m2, 4.0, rtol=1e-6)   # the 2-sigma contour
            assert e.texts[0].text == e.id.split("/")[1]
            speed = math.hypot(x[2], x[3])
            if speed >= 0.05:
                a = e.arrows[0]
                yaw = 2 * math.atan2(a.pose.orientation.z, a.pose.orientation.w)
                assert a.shaft_length == pytest.approx(speed)
                assert math.remainder(yaw - math.atan2(x[3], x[2]), 2 * math.pi) == \
                    pytest.approx(0.0, abs=1e-9)
                assert (a.pose.position.x, a.pose.position.y) == pytest.approx(tuple(x[:2]))
            seen += 1
    assert seen > 50
    rows = [r for _, _, m in log["/persons"] for r in m["people"]]
    assert rows == [r for f in frames for r in person_rows(f)]


def test_radars_and_transforms_are_the_poses(log, replay):
    names, poses, _ = replay
    scene = log["/radars"][0][2]
    assert [e.id for e in scene.entities] == [f"radar/{n}" for n in names]
    for e, pose in zip(scene.entities, poses):
        fov = np.array([[q.x, q.y] for q in e.lines[0].points])
        np.testing.assert_allclose(fov[0], pose[:2], atol=1e-12)
        arc = fov[1:-1] - pose[:2]
        np.testing.assert_allclose(np.linalg.norm(arc, axis=1), 6.0)
        bore = np.array([-np.sin(pose[2]), np.cos(pose[2])])
        off = np.degrees(np.arccos(np.clip(arc @ bore / 6.0, -1, 1)))
        assert off.max() == pytest.approx(60.0)
        assert {kv.key: float(kv.value) for kv in e.metadata} == pytest.approx(
            dict(zip(("x_m", "y_m", "phi_rad"), pose)), abs=1e-5)
        assert e.texts[0].text == e.id.split("/")[1]
    for t, pose in zip(log["/tf"][0][2].transforms, poses):
        assert (t.parent_frame_id, t.translation.x, t.translation.y) == ("world", *pose[:2])
        assert 2 * math.atan2(t.rotation.z, t.rotation.w) == pytest.approx(pose[2])


def test_points_are_each_radars_detections_in_the_reference_frame(log, replay):
    names, poses, frames = replay
    for i, name in enumerate(names):
        for (_, _, cloud), f in zip(log[f"/points/{name}"], frames):
            assert [fl.name for fl in cloud.fields] == ["x", "y", "z", "doppler_mps", "snr_db"]
            pts = np.frombuffer(cloud.data, dtype="<f4").reshape(-1, 5)
            z = f.centroids[name]
            theta = np.arcsin(z[:, 1] / np.pi)
            local = np.stack([z[:, 0] * np.sin(theta), z[:, 0] * np.cos(theta)], -1)
            c, s = np.cos(poses[i, 2]), np.sin(poses[i, 2])
            want = poses[i, :2] + local @ np.array([[c, s], [-s, c]])
            np.testing.assert_allclose(pts[:, :2], want, atol=1e-5)   # float32
            np.testing.assert_allclose(pts[:, 3], z[:, 2], atol=1e-6)


def test_an_existing_log_is_replaced_only_with_overwrite(replay, tmp_path):
    names, poses, frames = replay
    path = tmp_path / "v.mcap"
    path.write_bytes(b"old")
    with pytest.raises(FileFormatError, match="exists; pass --overwrite"):
        FoxgloveView(names, poses, ViewOptions(log_path=path))
    assert path.read_bytes() == b"old"
    view = FoxgloveView(names, poses, ViewOptions(log_path=path, overwrite=True))
    view.write(frames[0])
    assert path.read_bytes() == b"old"           # written beside it until closed
    view.close()
    assert path.read_bytes()[:8] == b"\x89MCAP0\r\n"
    assert [p.name for p in tmp_path.iterdir()] == ["v.mcap"]


@pytest.mark.parametrize("kwargs, match", [
    (dict(), "give a log_path, serve=True or both"),
    (dict(serve=True, port=70000), "port=70000"),
    (dict(serve=True, history_s=0.0), "history_s"),
    (dict(serve=True, fov_half_angle_rad=4.0), "fov_half_angle_rad"),
])
def test_view_options_are_checked(kwargs, match):
    with pytest.raises(ValidationError, match=match):
        ViewOptions(**kwargs)


def test_without_foxglove_the_error_names_the_extra(monkeypatch, tmp_path):
    import sys
    monkeypatch.setitem(sys.modules, "foxglove", None)
    with pytest.raises(MmsnapError, match=r'pip install "mmsnap_graph\[view\]"'):
        FoxgloveView(["S1"], [[0, 0, 0]], ViewOptions(log_path=tmp_path / "x.mcap"))


# -- the live WebSocket, on loopback -----------------------------------------

class _Client:
    """A minimal WebSocket client (RFC 6455) of Foxglove's protocol: frames
    read into a buffer that survives a read timeout."""

    def __init__(self, port: int) -> None:
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=10)
        key = base64.b64encode(os.urandom(16)).decode()
        self.sock.sendall((f"GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\n"
                           f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\n"
                           "Sec-WebSocket-Version: 13\r\n"
                           "Sec-WebSocket-Protocol: foxglove.sdk.v1\r\n\r\n").encode())
        self.buf = b""
        while b"\r\n\r\n" not in self.buf:
            self.buf += self.sock.recv(4096)
        self.head, self.buf = self.buf.split(b"\r\n\r\n", 1)

    def _fill(self, n: int) -> None:
        while len(self.buf) < n:
            chunk = self.sock.recv(65536)
            if not chunk:
                raise EOFError("the server closed the connection")
            self.buf += chunk

    def frame(self):
        """(opcode, payload) of the next frame (server frames are unmasked)."""
        self._fill(2)
        n, start = self.buf[1] & 0x7F, 2
        if n >= 126:
            start = 4 if n == 126 else 10
            self._fill(start)
            n = struct.unpack(">H" if n == 126 else ">Q", self.buf[2:start])[0]
        self._fill(start + n)
        op, data = self.buf[0] & 0x0F, self.buf[start:start + n]
        self.buf = self.buf[start + n:]
        return op, data

    def send(self, opcode: int, data: bytes) -> None:
        mask = os.urandom(4)
        n = len(data)
        size = bytes([0x80 | n]) if n < 126 else bytes([0x80 | 126]) + struct.pack(">H", n)
        self.sock.sendall(bytes([0x80 | opcode]) + size + mask +
                          bytes(b ^ mask[i % 4] for i, b in enumerate(data)))


def test_the_live_server_sends_the_people_to_a_subscriber(replay):
    """A client of Foxglove's WebSocket protocol on 127.0.0.1 (any free
    port): the channels advertised, /people subscribed, a frame's
    SceneUpdate received and decoded with the schema advertised. The frame is
    logged again (at most 50 times, 0.2 s apart) until the subscription has
    reached the server."""
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    names, poses, frames = replay
    view = FoxgloveView(names, poses, ViewOptions(serve=True, port=0))
    client = _Client(int(view.url.rsplit(":", 1)[1]))
    try:
        assert client.head.startswith(b"HTTP/1.1 101")
        channels, deadline = {}, time.monotonic() + 10
        while "/people" not in channels and time.monotonic() < deadline:
            op, data = client.frame()
            if op == 1:
                channels.update({c["topic"]: c for c in json.loads(data).get("channels", [])})
        assert {"/radars", "/people", "/tracks", "/points/S1", "/persons"} <= set(channels)
        people = channels["/people"]
        client.send(1, json.dumps({"op": "subscribe", "subscriptions": [
            {"id": 7, "channelId": people["id"]}]}).encode())
        f = next(f for f in frames if len(f.update.track_id))
        client.sock.settimeout(0.2)
        data = None
        for _ in range(50):
            view.write(f)
            try:
                op, data = client.frame()
                while op != 2:
                    op, data = client.frame()
                break
            except socket.timeout:
                continue
        assert data is not None and data[0] == 1            # binary message data
        sub, log_ns = struct.unpack("<IQ", data[1:13])
        assert sub == 7 and log_ns == round(f.time_s * 1e9)
        fds = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(people["schema"]))
        pool = descriptor_pool.DescriptorPool()
        for fd in fds.file:
            pool.Add(fd)
        cls = message_factory.GetMessageClass(pool.FindMessageTypeByName("foxglove.SceneUpdate"))
        msg = cls.FromString(data[13:])
        assert [e.id for e in msg.entities] == [f"person/{i}" for i in f.update.track_id]
        client.send(8, struct.pack(">H", 1000))             # close
    finally:
        client.sock.close()
        view.close()
