"""The fused people in Foxglove / Lichtblick: an MCAP log and a live WebSocket.

:class:`FoxgloveView` is a :class:`~mmsnap_graph.app.live.driver.FusedSink`
(``mmsnap live --view``, ``mmsnap replay --view``): each fused frame becomes
messages of Foxglove's well-known schemas (protobuf), written to an MCAP file
(``--view-log FILE.mcap``, opened later in Foxglove or the open-source
Lichtblick) and/or served live on a WebSocket (``--view``: connect Foxglove
or Lichtblick to ``ws://127.0.0.1:8765``). Optional extra: ``pip install
".[view]"`` (foxglove-sdk, no Python dependencies).

Topics, all in the frame ``world`` (the reference radar's, S1's: x along its
array axis, y along its boresight, metres):

- ``/radars`` (``foxglove.SceneUpdate``): each radar's field of view, its
  boresight arrow, its board and its name; sent at the start and every
  second (a viewer that connects late sees them);
- ``/tf`` (``foxglove.FrameTransforms``): ``world`` -> each radar's frame;
- ``/points/NAME`` (``foxglove.PointCloud``): each radar's points of the
  frame (fields ``x, y, z`` and ``doppler_mps``, ``snr_db``);
- ``/centroids`` (``foxglove.SceneUpdate``): each radar's torso centroids;
- ``/people`` (``foxglove.SceneUpdate``): per person ``person/ID``: the
  2-sigma position ellipse (:func:`~.scene.covariance_ellipse` of the 4x4
  covariance's position block), the velocity arrow (its length the distance
  walked in one second), the label ``ID``; the entities of the last frame are
  deleted first, so a track that ended disappears;
- ``/tracks`` (``foxglove.SceneUpdate``): each person's positions over the
  last ``history_s`` seconds;
- ``/persons`` (JSON): the frame's rows of ``mmsnap live``'s JSON lines, for
  Foxglove's Plot and Raw Messages panels.

Log times are the frames' times on the wall clock (``time_origin_s +
time_s``, nanoseconds).
"""

from __future__ import annotations

import contextlib
import math
import os
from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

from ..._atomic import atomic_path, refuse_existing
from ...errors import MmsnapError, ValidationError
from ..live.sinks import person_rows
from .scene import (ELLIPSE_SIGMA, FOV_HALF_ANGLE_RAD, FOV_RANGE_M, TrackHistory, boresight,
                    covariance_ellipse, detections_xy, field_of_view, id_color, node_color)

__all__ = ["ViewOptions", "FoxgloveView", "TOPICS", "WORLD_FRAME", "DEFAULT_PORT"]

#: The frame every topic is drawn in (the reference radar's).
WORLD_FRAME = "world"
#: The Foxglove WebSocket port (Foxglove's and Lichtblick's default).
DEFAULT_PORT = 8765
#: The topics, for docs and tests (``/points/NAME`` per radar).
TOPICS = ("/radars", "/tf", "/points/NAME", "/centroids", "/people", "/tracks", "/persons")
#: Seconds between two copies of the radars (``/radars``, ``/tf``).
RADARS_EVERY_S = 1.0

_PERSONS_SCHEMA = {
    "type": "object", "title": "mmsnap.persons",
    "properties": {"frame": {"type": "integer"}, "time_s": {"type": "number"},
                   "people": {"type": "array", "items": {"type": "object"}}}}


@dataclass(frozen=True, kw_only=True, slots=True)
class ViewOptions:
    """What :class:`FoxgloveView` writes and serves.

    log_path : write an MCAP file here (None: none); overwrite : replace an
    existing one. serve : start the WebSocket server on ``host:port`` (port
    0: any free port). history_s : seconds of track history drawn.
    fov_half_angle_rad, fov_range_m : the fields of view drawn. time_origin_s :
    the wall-clock time (Unix s) of ``time_s = 0``.
    """

    log_path: str | os.PathLike | None = None
    overwrite: bool = False
    serve: bool = False
    host: str = "127.0.0.1"
    port: int = DEFAULT_PORT
    history_s: float = 10.0
    fov_half_angle_rad: float = FOV_HALF_ANGLE_RAD
    fov_range_m: float = FOV_RANGE_M
    time_origin_s: float = 0.0

    def __post_init__(self) -> None:
        if self.log_path is None and not self.serve:
            raise ValidationError("ViewOptions: give a log_path, serve=True or both")
        if not (isinstance(self.port, int) and 0 <= self.port <= 65535):
            raise ValidationError(f"port={self.port!r} must be an integer in 0..65535")
        for name in ("history_s", "fov_range_m"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValidationError(f"{name}={v!r} must be finite and > 0")
        if not (0 < self.fov_half_angle_rad <= math.pi):
            raise ValidationError(f"fov_half_angle_rad={self.fov_half_angle_rad!r} must lie "
                                  "in (0, pi]")
        if not math.isfinite(self.time_origin_s):
            raise ValidationError(f"time_origin_s={self.time_origin_s!r} must be finite")


def _foxglove():
    try:
        import foxglove
        from foxglove import channels, messages
    except ImportError as exc:
        raise MmsnapError('the view needs foxglove-sdk: pip install "mmsnap_graph[view]" (or '
                          f'pip install ".[view]" from the repository) ({exc})') from None
    return foxglove, channels, messages


class FoxgloveView:
    """Fused frames -> Foxglove messages (module docstring).

    names : the radars, in node order; poses : (N, 3) their poses
    ``(x_m, y_m, phi_rad)`` in the reference frame; options : :class:`ViewOptions`.
    """

    def __init__(self, names: Sequence[str], poses, options: ViewOptions) -> None:
        fox, ch, self._m = _foxglove()
        self.names = tuple(names)
        self.poses = np.asarray(poses, dtype=float).reshape(len(self.names), 3)
        self.options = options
        self._stack = contextlib.ExitStack()
        self._ctx = fox.Context()
        self._server = None
        self.frames = 0
        self._last_radars_s = -math.inf
        self._history = TrackHistory(options.history_s)
        if options.log_path is not None:
            refuse_existing(options.log_path, overwrite=options.overwrite)
            tmp = self._stack.enter_context(atomic_path(options.log_path))
            writer = fox.open_mcap(tmp, allow_overwrite=True, context=self._ctx)
            self._stack.callback(writer.close)
        if options.serve:
            self._server = fox.start_server(name="mmsnap", host=options.host, port=options.port,
                                            context=self._ctx)
            self._stack.callback(self._server.stop)
        c = self._ctx
        self._radars = ch.SceneUpdateChannel("/radars", context=c)
        self._tf = ch.FrameTransformsChannel("/tf", context=c)
        self._points = {n: ch.PointCloudChannel(f"/points/{n}", context=c) for n in self.names}
        self._centroids = ch.SceneUpdateChannel("/centroids", context=c)
        self._people = ch.SceneUpdateChannel("/people", context=c)
        self._tracks = ch.SceneUpdateChannel("/tracks", context=c)
        self._persons = fox.Channel("/persons", schema=_PERSONS_SCHEMA, context=c)

    @property
    def url(self) -> str | None:
        """``ws://host:port`` of the live server (None without one)."""
        if self._server is None:
            return None
        return f"ws://{self.options.host}:{self._server.port}"

    # ------------------------------------------------------------------
    def write(self, frame) -> None:
        """Log one :class:`~mmsnap_graph.app.live.driver.LiveFrame`."""
        t_ns = int(round((self.options.time_origin_s + float(frame.time_s)) * 1e9))
        stamp = self._m.Timestamp(t_ns // 10**9, t_ns % 10**9)
        if frame.time_s - self._last_radars_s >= RADARS_EVERY_S or frame.time_s < \
                self._last_radars_s:
            self._radars.log(self._radar_scene(stamp), log_time=t_ns)
            self._tf.log(self._transforms(stamp), log_time=t_ns)
            self._last_radars_s = float(frame.time_s)
        for i, name in enumerate(self.names):
            if name in frame.points:
                xy = detections_xy(frame.points[name], self.poses[i])
                self._points[name].log(self._cloud(stamp, xy, frame.points[name]), log_time=t_ns)
        self._centroids.log(self._centroid_scene(stamp, frame.centroids), log_time=t_ns)
        u = frame.update
        ids = np.asarray(u.track_id)
        states = np.asarray(u.track_state).reshape(-1, 4)
        covs = np.asarray(u.track_covariance).reshape(-1, 4, 4)
        self._history.update(float(frame.time_s), ids, states[:, :2])
        self._people.log(self._people_scene(stamp, ids, states, covs, bool(u.ok)), log_time=t_ns)
        self._tracks.log(self._track_scene(stamp), log_time=t_ns)
        self._persons.log({"frame": int(frame.frame), "time_s": float(frame.time_s),
                           "people": person_rows(frame)}, log_time=t_ns)
        self.frames += 1

    def close(self) -> None:
        """Finish the MCAP file (moved into place) and stop the server."""
        self._stack.close()

    # ------------------------------------------------------------------
    def _color(self, rgb, a=1.0):
        return self._m.Color(r=rgb[0], g=rgb[1], b=rgb[2], a=a)

    def _line(self, xy, rgb, *, loop=False, thickness=0.03, z=0.0, a=1.0):
        m = self._m
        kind = m.LinePrimitiveLineType.LineLoop if loop else m.LinePrimitiveLineType.LineStrip
        return m.LinePrimitive(type=kind, thickness=thickness, color=self._color(rgb, a),
                               points=[m.Point3(x=float(x), y=float(y), z=z) for x, y in xy])

    def _yaw(self, yaw):
        return self._m.Quaternion(x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2))

    def _pose(self, x, y, yaw, z=0.0):
        m = self._m
        return m.Pose(position=m.Vector3(x=float(x), y=float(y), z=z), orientation=self._yaw(yaw))

    def _radar_scene(self, stamp):
        m, o = self._m, self.options
        entities = []
        for i, name in enumerate(self.names):
            pose, rgb = self.poses[i], node_color(i)
            fov = field_of_view(pose, half_angle_rad=o.fov_half_angle_rad, range_m=o.fov_range_m)
            tip = boresight(pose)
            yaw = math.atan2(tip[1, 1] - tip[0, 1], tip[1, 0] - tip[0, 0])
            entities.append(m.SceneEntity(
                timestamp=stamp, frame_id=WORLD_FRAME, id=f"radar/{name}",
                lines=[self._line(fov, rgb, thickness=0.02, a=0.8)],
                arrows=[m.ArrowPrimitive(pose=self._pose(pose[0], pose[1], yaw),
                                         shaft_length=0.35, shaft_diameter=0.03,
                                         head_length=0.12, head_diameter=0.08,
                                         color=self._color(rgb))],
                cubes=[m.CubePrimitive(pose=self._pose(pose[0], pose[1], pose[2]),
                                       size=m.Vector3(x=0.12, y=0.04, z=0.08),
                                       color=self._color(rgb))],
                texts=[m.TextPrimitive(pose=self._pose(pose[0], pose[1], 0.0, z=0.25),
                                       billboard=True, font_size=14.0, scale_invariant=True,
                                       color=self._color(rgb), text=name)],
                metadata=[m.KeyValuePair(key=k, value=f"{v:.6g}") for k, v in
                          zip(("x_m", "y_m", "phi_rad"), pose)]))
        return m.SceneUpdate(entities=entities)

    def _transforms(self, stamp):
        m = self._m
        return m.FrameTransforms(transforms=[
            m.FrameTransform(timestamp=stamp, parent_frame_id=WORLD_FRAME, child_frame_id=name,
                             translation=m.Vector3(x=float(p[0]), y=float(p[1]), z=0.0),
                             rotation=self._yaw(float(p[2])))
            for name, p in zip(self.names, self.poses)])

    def _cloud(self, stamp, xy, det):
        m = self._m
        n = xy.shape[0]
        rec = np.zeros(n, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("doppler", "<f4"),
                                 ("snr", "<f4")])
        rec["x"], rec["y"] = xy[:, 0], xy[:, 1]
        if n:  # a LiveFrame's points are Detections
            rec["doppler"] = det.doppler_mps
            rec["snr"] = det.snr_db if det.snr_db is not None else np.nan
        f32 = m.PackedElementFieldNumericType.Float32
        fields = [m.PackedElementField(name=name, offset=4 * k, type=f32)
                  for k, name in enumerate(("x", "y", "z", "doppler_mps", "snr_db"))]
        return m.PointCloud(timestamp=stamp, frame_id=WORLD_FRAME, point_stride=20,
                            fields=fields, data=rec.tobytes())

    def _centroid_scene(self, stamp, centroids: Mapping):
        m = self._m
        entities = []
        for i, name in enumerate(self.names):
            z = centroids.get(name)
            xy = detections_xy(z, self.poses[i]) if z is not None else np.zeros((0, 2))
            entities.append(m.SceneEntity(
                timestamp=stamp, frame_id=WORLD_FRAME, id=f"centroids/{name}",
                spheres=[m.SpherePrimitive(pose=self._pose(x, y, 0.0),
                                           size=m.Vector3(x=0.12, y=0.12, z=0.12),
                                           color=self._color(node_color(i)))
                         for x, y in xy]))
        return m.SceneUpdate(entities=entities)

    def _people_scene(self, stamp, ids, states, covs, ok):
        m = self._m
        entities = []
        for tid, x, p in zip(ids.tolist(), states, covs):
            rgb = id_color(tid)
            speed = math.hypot(x[2], x[3])
            arrows = [] if speed < 0.05 else [m.ArrowPrimitive(
                pose=self._pose(x[0], x[1], math.atan2(x[3], x[2])), shaft_length=speed,
                shaft_diameter=0.04, head_length=0.15, head_diameter=0.12,
                color=self._color(rgb))]
            entities.append(m.SceneEntity(
                timestamp=stamp, frame_id=WORLD_FRAME, id=f"person/{tid}",
                lines=[self._line(covariance_ellipse(x[:2], p[:2, :2], n_sigma=ELLIPSE_SIGMA),
                                  rgb, loop=True)],
                arrows=arrows,
                spheres=[m.SpherePrimitive(pose=self._pose(x[0], x[1], 0.0),
                                           size=m.Vector3(x=0.1, y=0.1, z=0.1),
                                           color=self._color(rgb))],
                texts=[m.TextPrimitive(pose=self._pose(x[0], x[1], 0.0, z=0.3), billboard=True,
                                       font_size=16.0, scale_invariant=True,
                                       color=self._color(rgb), text=str(tid))],
                metadata=[m.KeyValuePair(key="id", value=str(tid)),
                          m.KeyValuePair(key="status", value="tracked" if ok else "predicted")]))
        every = m.SceneEntityDeletion(timestamp=stamp, type=m.SceneEntityDeletionType.All)
        return m.SceneUpdate(deletions=[every], entities=entities)

    def _track_scene(self, stamp):
        m = self._m
        entities = [m.SceneEntity(timestamp=stamp, frame_id=WORLD_FRAME, id=f"track/{tid}",
                                  lines=[self._line(xy, id_color(tid), thickness=0.02, a=0.7)])
                    for tid, xy in self._history.lines().items() if len(xy) > 1]
        every = m.SceneEntityDeletion(timestamp=stamp, type=m.SceneEntityDeletionType.All)
        return m.SceneUpdate(deletions=[every], entities=entities)

