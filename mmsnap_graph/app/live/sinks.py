"""Consumers of fused live frames (:class:`~.driver.FusedSink`).

- :class:`JsonLinesSink`: one JSON object per person per frame, ``frame,
  time_s, id, x_m, y_m, vx_mps, vy_mps, covariance`` (4x4, state order x, y,
  vx, vy), ``status`` (``"tracked"``; ``"predicted"`` when the frame was
  flagged and the tracker only predicted), flushed line by line;
- :class:`CentroidLog`: the centroids each board gave each frame, for the
  recording of ``mmsnap live --record`` (so that ``mmsnap replay`` of it
  streams exactly what live fused);
- :class:`LatencyLog`: host time from a frame's last byte to its fused output;
- :class:`SelfCheckSink`: the covariance self-check without truth
  (:class:`~mmsnap_graph.fusion.recording.consistency.ConsistencyMonitor`)
  over the fused frames, each change of its verdict a JSON line (``mmsnap
  live`` and ``mmsnap replay``).
"""

from __future__ import annotations

import json
import time

import numpy as np

from ...data.recording import Detections

__all__ = ["JsonLinesSink", "CentroidLog", "LatencyLog", "SelfCheckSink", "person_rows"]


def person_rows(frame) -> list[dict]:
    """The JSON objects of one fused frame (module docstring)."""
    u = frame.update
    status = "tracked" if u.ok else "predicted"
    return [{"frame": int(frame.frame), "time_s": float(frame.time_s), "id": int(tid),
             "x_m": float(x[0]), "y_m": float(x[1]), "vx_mps": float(x[2]),
             "vy_mps": float(x[3]), "covariance": np.asarray(p).tolist(), "status": status}
            for tid, x, p in zip(u.track_id.tolist(), u.track_state, u.track_covariance)]


class JsonLinesSink:
    """Write :func:`person_rows` to a text stream, one line each, flushed."""

    def __init__(self, stream) -> None:
        self.stream = stream
        self.lines = 0

    def write(self, frame) -> None:
        rows = person_rows(frame)
        if rows:
            self.stream.write("".join(json.dumps(r) + "\n" for r in rows))
            self.stream.flush()
            self.lines += len(rows)

    def close(self) -> None:
        self.stream.flush()


class CentroidLog:
    """Each board's centroids per fused frame, as :class:`Detections`."""

    def __init__(self) -> None:
        self._rows: dict[str, list] = {}

    def write(self, frame) -> None:
        for name, z in frame.centroids.items():
            if len(z):
                self._rows.setdefault(name, []).append((frame.frame, np.asarray(z)))

    def close(self) -> None:
        pass

    def detections(self, name: str) -> Detections:
        rows = self._rows.get(name, [])
        if not rows:
            return Detections.empty()
        z = np.concatenate([r for _, r in rows])
        f = np.concatenate([np.full(len(r), s, dtype=np.int64) for s, r in rows])
        return Detections(frame=f, range_m=z[:, 0], omega_rad=z[:, 1], doppler_mps=z[:, 2])


class LatencyLog:
    """Seconds from each fused frame's last byte read to its output."""

    def __init__(self) -> None:
        self.latency_s: list[float] = []

    def write(self, frame) -> None:
        if frame.last_byte_s is not None:      # None: a slot no board gave
            self.latency_s.append(time.monotonic() - frame.last_byte_s)   # after the sinks before it

    def close(self) -> None:
        pass

    def summary(self) -> str:
        lat = np.asarray(self.latency_s) * 1e3
        if not lat.size:
            return "no frame fused"
        return (f"{lat.size} frames fused; latency from the last byte to the fused output "
                f"median {np.median(lat):.2f} ms, p99 {np.percentile(lat, 99):.2f} ms")


class SelfCheckSink:
    """The covariance self-check over streamed frames, in bounded memory.

    Each fused frame's groups go to a
    :class:`~mmsnap_graph.fusion.recording.consistency.ConsistencyMonitor`;
    each time its verdict changes (the first once there is enough data),
    ``log`` gets one JSON line ``{"type": "self_check", "frame": N,
    "self_check": {...}}`` and, when
    the covariances fail the check, the loud sentence after ``mmsnap
    COMMAND:``. :meth:`report` is the verdict over everything so far.
    ``prior`` is the stream's :class:`~mmsnap_graph.data.noise.GaussianPrior`
    (None: ML)."""

    def __init__(self, *, frame_period_s: float, prior, log, command: str) -> None:
        from ...fusion.recording.consistency import ConsistencyMonitor

        self.monitor = ConsistencyMonitor()
        self.frame_period_s, self.prior = float(frame_period_s), prior
        self._log, self._command = log, command

    def add(self, frame: int, update) -> None:
        """One :class:`~mmsnap_graph.fusion.stream.frame_stream.StreamUpdate`
        at frame number ``frame``."""
        self.monitor.add_update(update, frame, frame_period_s=self.frame_period_s,
                                prior=self.prior)
        report = self.monitor.new_verdict()
        if report is not None:
            self._log(json.dumps({"type": "self_check", "frame": int(frame),
                                   "self_check": report.to_dict()}))
            if report.warning:
                self._log(f"mmsnap {self._command}: {report.warning}")

    def write(self, frame) -> None:
        self.add(frame.frame, frame.update)

    def close(self) -> None:
        pass

    def report(self):
        """The :class:`~mmsnap_graph.fusion.recording.consistency.ConsistencyReport`
        of every frame so far."""
        return self.monitor.report()
