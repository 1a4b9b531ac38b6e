"""``mmsnap live --refine``: the calibration refined as people walk, in its
own process (docs/LIVE.md, "Refining the calibration live").

:class:`RefineSink` is a :class:`~.driver.FusedSink` placed after the JSON
lines: each fused slot's centroids are handed (in batches of
:data:`BATCH_FRAMES` slots, through a pipe) to a child process running
:class:`~mmsnap_graph.calibration.online.OnlineRefinement` at a lower
priority (``nice`` +10), so the windows' calibrations and the monitor never
hold up a fused frame. The child sends back each
:class:`~mmsnap_graph.calibration.online.PoseUpdate`; the sink takes the
ones that arrived when the next slot is written, at a frame boundary: the
poses (and, when the stream weighs pose covariances, their covariances) go
to the stream (:meth:`~mmsnap_graph.fusion.stream.frame_stream.FrameStream.set_poses`)
for the slots after it, each update is one JSON line (``"type":
"calibration"``) on the log (standard error), and the child writes the
current calibration JSON atomically (``--refined-calibration``) after each.
"""

from __future__ import annotations

import json
import multiprocessing
import os
import queue
import threading
import time
import traceback
from typing import Callable, Mapping, Sequence

import numpy as np

__all__ = ["BATCH_FRAMES", "RefineSink", "below_live", "refinement_noise"]

#: Slots per message to the refinement process (a second at 20 fps).
BATCH_FRAMES = 20
#: How long closing waits for the refinement process's last updates (s).
_CLOSE_TIMEOUT_S = 120.0


def refinement_noise(noise):
    """The one :class:`~mmsnap_graph.data.noise.MeasurementNoise` the
    monitor whitens by: ``noise`` itself, or the first node's of a
    per-node mapping or sequence."""
    if isinstance(noise, Mapping):
        return next(iter(noise.values()))
    if isinstance(noise, (tuple, list)):
        return noise[0]
    return noise


def _one_target(names, frame) -> dict:
    """The monitor's rows of a slot: each node's row of the slot's one fused
    target when the stream fused exactly one, successfully ({} otherwise:
    clutter or several people, which the monitor does not follow)."""
    u = frame.update
    if u is None or u.index < 0 or len(u.status) != 1 or u.status[0] != 0:
        return {}
    return {n: np.asarray(frame.centroids[n][m], dtype=float)
            for n, m in zip(names, u.members[0]) if m >= 0 and n in frame.centroids}


def below_live() -> None:
    """Lower this process below ``mmsnap live`` (``nice`` +10): a helper
    process of live (the refinement, the learned walls' worker) never holds
    up a fused frame."""
    try:
        os.nice(10)
    except OSError:                      # pragma: no cover - not allowed here
        pass


def _serve(conn, options: dict, json_path) -> None:
    """The refinement process: batches of ``(slot, centroids)`` in, updates
    out (``("update", PoseUpdate)``, then ``("done", summary)`` or
    ``("error", text)``)."""
    below_live()
    inbox: queue.Queue = queue.Queue()

    def read():                          # drain the pipe: the sender never blocks
        while True:
            try:
                msg = conn.recv()
            except EOFError:
                msg = None
            inbox.put(msg)
            if msg is None:
                return

    threading.Thread(target=read, daemon=True).start()
    try:
        from mmsnap_graph.calibration.online import OnlineRefinement
        from mmsnap_graph.io.calibration import write_calibration_json
        refinement = OnlineRefinement(**options)
        while True:
            batch = inbox.get()
            if batch == "sync":
                conn.send(("synced", None))
                continue
            ups = refinement.finish() if batch is None else [
                u for slot, c, one in batch for u in refinement.add(slot, c, one)]
            for u in ups:
                if json_path is not None and u.reason != "change":
                    write_calibration_json(json_path, refinement.calibration())
                conn.send(("update", u))
            if batch is None:
                conn.send(("done", {"windows": refinement.windows,
                                    "combined": refinement.combined,
                                    "skipped": list(refinement.skipped)}))
                return
    except Exception:                    # noqa: BLE001 - reported to the parent
        conn.send(("error", traceback.format_exc()))


class RefineSink:
    """The refinement of ``stream``'s poses (module doc).

    names, poses : the boards in the stream's order and their (N, 3)
    poses; covariances : name -> (3, 3) or None; noise : the stored
    calibration's; options : more of
    :class:`~mmsnap_graph.calibration.online.OnlineRefinement`'s
    (``window_s``, ``monitor``, ...); json_path : the calibration JSON
    written after each update (None: none); log : called with each JSON
    line.
    """

    def __init__(self, stream, names: Sequence[str], poses, *, frame_period_s: float,
                 covariances: Mapping | None = None, noise=None, json_path=None,
                 log: Callable[[str], None] = print, **options) -> None:
        self.stream, self.names, self.log = stream, tuple(names), log
        opts = dict(node_poses={n: np.asarray(p, float) for n, p in zip(self.names, poses)},
                    frame_period_s=float(frame_period_s),
                    covariances=None if covariances is None else dict(covariances), **options)
        if noise is not None:
            opts["noise"] = refinement_noise(noise)
        # Validated here, where a bad option is the command's error, not the child's.
        from mmsnap_graph.calibration.online import OnlineRefinement
        OnlineRefinement(**{**opts, "monitor": False})
        ctx = multiprocessing.get_context("spawn")
        self._conn, child = ctx.Pipe()
        self._proc = ctx.Process(target=_serve, args=(child, opts, json_path), daemon=True,
                                 name="mmsnap-refine")
        self._proc.start()
        child.close()
        self._batch: list = []
        self.updates: list = []
        self.summary: dict = {}
        self.error = ""

    def write(self, frame) -> None:
        self._batch.append((frame.frame, {n: np.asarray(z) for n, z in frame.centroids.items()
                                          if len(z)}, _one_target(self.names, frame)))
        if len(self._batch) >= BATCH_FRAMES:
            self._send()
        self._receive()

    def _send(self) -> None:
        if self._batch and not self.error:
            try:
                self._conn.send(self._batch)
            except (BrokenPipeError, EOFError, OSError) as exc:
                self.error = f"the refinement process stopped: {exc}"
        self._batch = []

    def sync(self, timeout_s: float = _CLOSE_TIMEOUT_S) -> None:
        """Send the slots held and wait until the refinement process has
        taken every slot sent, its updates applied (tests, benchmarks)."""
        self._send()
        if not self.error:
            self._conn.send("sync")
            self._receive(timeout_s, until="synced")

    def _receive(self, timeout_s: float = 0.0, until: str = "done") -> bool:
        """Take the messages that arrived (waiting up to ``timeout_s`` for
        each); True when the child said ``until`` or failed."""
        try:
            while not self.error and self._conn.poll(timeout_s):
                kind, value = self._conn.recv()
                if kind == "update":
                    self._apply(value)
                elif kind == "done":
                    self.summary = value
                    return True
                elif kind == "synced":
                    if until == "synced":
                        return True
                else:
                    self.error = value.strip().splitlines()[-1]
                    self.log(f"refinement failed: {self.error}")
        except (EOFError, OSError) as exc:
            self.error = self.error or f"the refinement process stopped: {exc}"
        return bool(self.error)

    def _apply(self, update) -> None:
        """One update at a frame boundary: the stream's poses, a JSON line."""
        self.updates.append(update)
        if update.reason != "change":
            poses = np.array([update.poses[n] for n in self.names], dtype=float)
            covs = self.stream.pose_covariances
            if covs is not None:
                covs = np.array(covs, dtype=float)
                for i, n in enumerate(self.names):
                    c = np.asarray(update.covariances[n], dtype=float)
                    if np.all(np.isfinite(c)) and n in update.nodes:
                        covs[i] = c
            self.stream.set_poses(poses, covs)
        self.log(json.dumps(update.to_json()))

    def report(self) -> str:
        """One line: the windows calibrated, combined, left out (and why), the updates."""
        if self.error:
            return f"refinement: failed: {self.error}"
        s = self.summary
        skipped = s.get("skipped", [])
        why = f" ({'; '.join(skipped[-3:])})" if skipped else ""
        kinds = [u.reason for u in self.updates]
        return (f"refinement: {s.get('windows', 0)} window(s) calibrated, "
                f"{s.get('combined', 0)} combined, {len(skipped)} left out{why}; "
                f"{kinds.count('change')} move(s) noticed, {kinds.count('recalibrated')} "
                f"re-calibration(s)")

    def close(self) -> None:
        """Send what is held, let the child finish its frames, take its last updates."""
        self._send()
        if not self.error:
            try:
                self._conn.send(None)
            except (BrokenPipeError, OSError):
                pass
            deadline = time.monotonic() + _CLOSE_TIMEOUT_S
            while time.monotonic() < deadline:
                if self._receive(timeout_s=1.0):
                    break
                if not self._proc.is_alive() and not self._conn.poll():
                    self.error = "the refinement process ended without its last updates"
                    break
        self._proc.join(timeout=5.0)
        if self._proc.is_alive():
            self._proc.terminate()
        self._conn.close()
