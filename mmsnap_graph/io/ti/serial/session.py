"""Several boards at once: open their ports, send their ``.cfg``, read them on
one clock (docs/LIVE.md). ``mmsnap record`` and ``mmsnap live`` both run a
:class:`BoardSession`.

Start: each data port is opened and its :class:`~.reader.BoardReader` started
first (so the first frame after ``sensorStart`` is not lost), then each
``.cfg`` is sent on its CLI port (:func:`~.console.send_cfg`; boards without
a CLI port, or with ``send_cfg=False``, only stream). Every frame goes to one
thread-safe queue, :attr:`BoardSession.frames`. Stop: the readers end, each
board with a CLI port gets ``sensorStop`` (best effort), the ports close.

:class:`FrameCollector` keeps the frames and makes one
:class:`~mmsnap_graph.data.recording.Recording` of them, every board on the
common clock (frame = slot of :class:`~.timing.BoardClock`).
"""

from __future__ import annotations

import queue
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from ....errors import ConfigurationError, DeviceError, ValidationError
from ..cfg import TIMING_ONLY_LAYOUT, read_ti_cfg
from ..point_cloud import Mounting, PointCloud3D, recording_from_point_clouds
from .boards import CLI_BAUD, DATA_BAUD, BoardSpec, resolve_port
from .console import REPLY_TIMEOUT_S, send_cfg, send_command
from .reader import READ_TIMEOUT_S, BoardFrame, BoardReader

__all__ = ["BoardTiming", "board_timing", "BoardSession", "FrameCollector", "open_port",
           "board_frame_offsets"]

#: Frames the session's queue holds before a reader waits (a stalled consumer;
#: 30 s of 4 boards at 20 fps).
QUEUE_FRAMES = 2400


@dataclass(frozen=True, kw_only=True, slots=True)
class BoardTiming:
    """What a board's ``.cfg`` says about its output: ``frame_period_s``,
    ``n_sub_frames`` (1 for a legacy frame), ``mount`` ((height_m, tilt_deg)
    from ``sensorPosition``, or None), ``max_range_m`` (the farthest range
    its chirps measure, of the first sub-frame; None without a ``.cfg``)."""

    frame_period_s: float
    n_sub_frames: int = 1
    mount: tuple | None = None
    max_range_m: float | None = None


def board_timing(spec: BoardSpec, frame_period_s: float | None = None) -> BoardTiming:
    """The timing of ``spec``'s ``.cfg`` (``frame_period_s`` overrides its
    period; without a ``.cfg`` it is required and one sub-frame assumed)."""
    if spec.cfg is None:
        if frame_period_s is None:
            raise ValidationError(f"board {spec.name}: no .cfg to read the frame period from: "
                                  "give the board's .cfg (NAME=CLI,DATA,CFG) or --frame-period")
        return BoardTiming(frame_period_s=float(frame_period_s))
    ti = read_ti_cfg(spec.cfg, layout=TIMING_ONLY_LAYOUT, ignore_unknown=True)
    mount = None
    if ti.sensor_height_m is not None:
        mount = (ti.sensor_height_m, float(np.rad2deg(ti.elevation_tilt_rad or 0.0)))
    period = ti.configs[0].frame_period_s if frame_period_s is None else float(frame_period_s)
    return BoardTiming(frame_period_s=period, n_sub_frames=ti.n_sub_frames if ti.advanced else 1,
                       mount=mount, max_range_m=float(ti.configs[0].max_range_m))


def open_port(port: str, baud: int, *, timeout_s: float, board: str, role: str):
    """A pyserial port (8N1), or :class:`DeviceError` naming the board and role."""
    import serial
    path = resolve_port(port, default_index=0 if role == "CLI" else 1)
    try:
        return serial.Serial(path, baudrate=baud, timeout=timeout_s, bytesize=8, parity="N",
                             stopbits=1)
    except (serial.SerialException, OSError, ValueError) as exc:
        raise DeviceError(f"board {board}: cannot open its {role} port {path}: {exc} (mmsnap "
                          "record --list-ports shows the ports)") from None


class BoardSession:
    """Run boards (module docstring). specs : the boards; frame_period_s :
    overrides the ``.cfg``'s (required for boards without one); send_cfg :
    send each ``.cfg`` (False: the boards already run); demo : the demo
    (``"auto"``: detected); t0_s : host time of frame 0 (default: now)."""

    def __init__(self, specs: Sequence[BoardSpec], *, frame_period_s: float | None = None,
                 send_cfg: bool = True, demo: str = "auto", t0_s: float | None = None,
                 reply_timeout_s: float = REPLY_TIMEOUT_S,
                 log: Callable[[str], None] = lambda text: None) -> None:
        names = [s.name for s in specs]
        if not specs or len(set(names)) != len(names):
            raise ValidationError(f"boards must be named once each, got {names}")
        self.specs = list(specs)
        self.timing = {s.name: board_timing(s, frame_period_s) for s in self.specs}
        periods = {name: t.frame_period_s for name, t in self.timing.items()}
        if max(periods.values()) - min(periods.values()) > 1e-9:
            raise ConfigurationError(f"the boards run different frame periods {periods} s: "
                                     "one common clock needs one frame period")
        self.frame_period_s = next(iter(periods.values()))
        self.send = bool(send_cfg)
        self.demo = demo
        self.t0_s = time.monotonic() if t0_s is None else float(t0_s)
        self.reply_timeout_s = reply_timeout_s
        self.log = log
        self.frames: queue.Queue[BoardFrame] = queue.Queue(maxsize=QUEUE_FRAMES)
        #: The most frames the queue held when one was taken (its bound: QUEUE_FRAMES).
        self.max_queued = 0
        self.readers: dict[str, BoardReader] = {}
        self._ports: list = []
        self._cli: dict[str, Any] = {}
        self.replies: dict[str, list] = {}

    def __enter__(self) -> "BoardSession":
        try:
            self.start()
        except BaseException:
            self.stop()
            raise
        return self

    def __exit__(self, *exc) -> bool:
        self.stop()
        return False

    def start(self) -> None:
        for spec in self.specs:
            port = open_port(spec.data_port, DATA_BAUD, timeout_s=READ_TIMEOUT_S,
                             board=spec.name, role="data")
            self._ports.append(port)
            timing = self.timing[spec.name]
            reader = BoardReader(spec.name, port, self.frames.put,
                                 frame_period_s=self.frame_period_s, t0_s=self.t0_s,
                                 n_sub_frames=timing.n_sub_frames, demo=self.demo)
            self.readers[spec.name] = reader
            reader.start()
        for spec in self.specs:
            if spec.cli_port is None:
                continue
            cli = open_port(spec.cli_port, CLI_BAUD, timeout_s=0.05, board=spec.name,
                            role="CLI")
            self._ports.append(cli)
            self._cli[spec.name] = cli
            if self.send and spec.cfg is not None:
                text = Path(spec.cfg).read_text(encoding="utf-8", errors="replace")
                self.replies[spec.name] = send_cfg(cli, text, board=spec.name,
                                                   timeout_s=self.reply_timeout_s)
                self.log(f"{spec.name}: sent {spec.cfg} ({len(self.replies[spec.name])} "
                         "commands, each answered Done)")

    def stop(self) -> None:
        for reader in self.readers.values():
            reader.stop()
        for reader in self.readers.values():
            if reader.is_alive():
                reader.join(timeout=5 * READ_TIMEOUT_S + 1.0)
        for name, cli in self._cli.items():
            if self.send:
                try:
                    send_command(cli, "sensorStop", board=name, timeout_s=1.0)
                except (ConfigurationError, DeviceError, OSError) as exc:
                    self.log(f"{name}: sensorStop at the end: {exc}")
        for port in self._ports:
            try:
                port.close()
            except OSError:
                pass
        self._ports.clear()
        self._cli.clear()

    def errors(self) -> dict[str, BaseException]:
        """The readers that ended with an error."""
        return {n: r.error for n, r in self.readers.items() if r.error is not None}


def board_frame_offsets(frames: Sequence[BoardFrame]) -> np.ndarray:
    """(M, 2) int rows ``(slot, offset)``: from ``slot`` on, a frame's slot
    minus the board's frame counter is ``offset``; a row where it changes
    (the first frame, each re-anchor of the board's clock or restart of its
    counter, :class:`~.timing.BoardClock`)."""
    slot = np.array([f.slot for f in frames], dtype=np.int64)
    offset = slot - np.array([f.frame_number for f in frames], dtype=np.int64)
    rows = np.flatnonzero(np.diff(offset, prepend=offset[:1] - 1))
    return np.column_stack([slot[rows], offset[rows]])


class FrameCollector:
    """The frames of a session, kept per board, and the recording they make
    (``t0_s``: the session's host time of slot 0, kept in the metadata as
    ``host_t0_s``)."""

    def __init__(self, names: Sequence[str], frame_period_s: float,
                 t0_s: float | None = None) -> None:
        self.frame_period_s = float(frame_period_s)
        self.t0_s = t0_s
        self.frames: dict[str, list[BoardFrame]] = {n: [] for n in names}

    def add(self, frame: BoardFrame) -> None:
        self.frames[frame.board].append(frame)

    def clouds(self) -> dict[str, PointCloud3D]:
        """Each board's points with their slot as frame number (every slot with a
        frame listed, points or not)."""
        out = {}
        for name, frames in self.frames.items():
            n = [f.n_points for f in frames]
            cols = {c: np.concatenate([f.points[c] for f in frames]) if frames else np.zeros(0)
                    for c in ("x", "y", "z", "doppler", "snr", "noise")}
            slot = np.repeat(np.array([f.slot for f in frames], dtype=np.int64), n)
            out[name] = PointCloud3D(frame=slot, x_m=cols["x"], y_m=cols["y"], z_m=cols["z"],
                                     doppler_mps=cols["doppler"], snr_db=cols["snr"],
                                     noise_db=cols["noise"],
                                     frames=np.array([f.slot for f in frames], dtype=np.int64))
        return out

    def recording(self, *, mounting: Mapping[str, Mounting],
                  height_band_m: tuple[float, float] | None = None,
                  metadata: Mapping[str, Any] | None = None):
        """One :class:`~mmsnap_graph.data.recording.Recording`, the boards on the
        common clock; per board its counters in the metadata."""
        md: dict[str, Any] = {"source": "ti-live", "frame_clock": "host"}
        if self.t0_s is not None:        # the host's monotonic clock at slot 0
            md["host_t0_s"] = float(self.t0_s)
        for name, frames in self.frames.items():
            if frames:
                md[f"{name}_board_frame_offset"] = int(frames[0].slot - frames[0].frame_number)
                md[f"{name}_board_frame_offsets"] = board_frame_offsets(frames)
                md[f"{name}_demo"] = frames[0].demo
        md.update(metadata or {})
        return recording_from_point_clouds(self.clouds(), frame_period_s=self.frame_period_s,
                                           mounting=dict(mounting), height_band_m=height_band_m,
                                           metadata=md, common_frames=True)
