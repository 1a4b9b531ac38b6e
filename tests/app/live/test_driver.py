"""The live driver (mmsnap_graph.app.live.driver) against ``mmsnap replay``
of the recording it makes: the same frames pushed, the same rows, whatever
slots the boards dropped (docs/LIVE.md, "Live and replay")."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from mmsnap_graph.app.cli import main
from mmsnap_graph.app.live.driver import (LiveFusion, live_calibration, live_recording,
                                          live_stream)
from mmsnap_graph.app.live.sinks import CentroidLog, JsonLinesSink
from mmsnap_graph.fusion.options import FusionOptions
from mmsnap_graph.fusion.stream.frame_stream import STREAM_CONFIG
from mmsnap_graph.io import read_fused, write_recording
from mmsnap_graph.io.ti.point_cloud import Mounting
from mmsnap_graph.io.ti.serial.reader import BoardFrame
from mmsnap_graph.io.ti.serial.session import FrameCollector

from ti_samples import FRAME_PERIOD_S, MOUNTS, lift, simulated

N = 90
#: Slots every board dropped, and one board dropped (S2, slot 12).
DROPPED_BY_ALL = {30, 31}
#: Slots in which no board has a point: a gap longer than the tracker's
#: max_misses (5), whose end the stream is not given (as replay skips it).
EMPTY = set(range(50, 64))


def _board_frames(rec):
    out = []
    for name in ("S1", "S2"):
        det = rec.nodes[name].point_cloud
        height, tilt = MOUNTS[name]
        xyz, dop = lift(det, height, tilt, seed=1)
        for f in range(N):
            if f in DROPPED_BY_ALL or (name == "S2" and f == 12):
                continue
            rows = (det.frame == f) & (f not in EMPTY)
            pts = {"x": xyz[rows, 0], "y": xyz[rows, 1], "z": xyz[rows, 2], "doppler": dop[rows],
                   "snr": det.snr_db[rows], "noise": np.full(rows.sum(), 45.0)}
            out.append(BoardFrame(board=name, slot=f, frame_number=f + 1, host_time_s=0.0,
                                  start_s=0.0, points=pts))
    out.sort(key=lambda b: (b.slot, b.board))
    return out


class _Rows:
    """A sink keeping each pushed frame's fused rows by their rows in the
    recording's centroids (as /fused's detection_index)."""

    def __init__(self, names):
        self.names, self.before, self.rows = names, {n: 0 for n in names}, {}

    def write(self, frame):
        u = frame.update
        if u.index >= 0:
            for state, status, members in zip(u.state, u.status, u.members):
                index = tuple(int(self.before[n] + m) if m >= 0 else -1
                              for n, m in zip(self.names, members))
                self.rows[(frame.frame, index)] = (int(status), np.asarray(state))
        for n, z in frame.centroids.items():
            self.before[n] += len(z)

    def close(self):
        pass


def _live(tmp_path, config):
    """Run the driver over the boards' frames (module constants); returns
    (live, stream, its JSON lines' file, the calibration JSON, the
    recording, the rows sink)."""
    rec = simulated(N, seed=1)
    names = ("S1", "S2")
    poses = {n: rec.truth.node_poses[n] for n in names}
    cal = tmp_path / "cal.json"
    # S2's pose uncertain and a reflection depth: both in live's covariances
    # and ranges as in replay's.
    covariance = {"S1": None, "S2": np.diag([0.02, 0.02, 0.01]).tolist()}
    cal.write_text(json.dumps({"range_offset_m": 0.04, "nodes": {
        n: {"pose": list(map(float, p)), "covariance": covariance[n]}
        for n, p in poses.items()}}))
    mounts = {n: Mounting(height_m=MOUNTS[n][0], tilt_rad=MOUNTS[n][1]) for n in names}
    live_poses, stored = live_calibration(cal, names)
    assert stored.range_offset_m == 0.04 and set(stored.pose_covariances) == {"S2"}
    stream = live_stream(names, live_poses, frame_period_s=FRAME_PERIOD_S, config=config,
                         noise=stored.noise, pose_covariances=stored.pose_covariances,
                         range_offset_m=stored.range_offset_m)
    out = tmp_path / "live.jsonl"
    collector, centroids, fused = FrameCollector(names, FRAME_PERIOD_S), CentroidLog(), \
        _Rows(names)
    with open(out, "w", encoding="utf-8") as f:
        # t0 far ahead: no slot is overdue, each waits for every board (or the flush).
        live = LiveFusion(names, stream, mounting=mounts, frame_period_s=FRAME_PERIOD_S,
                          t0_s=1e12, sinks=[JsonLinesSink(f), centroids, fused])
        for frame in _board_frames(rec):
            collector.add(frame)
            live.add(frame)
        live.flush()
    h5 = tmp_path / "live.h5"
    write_recording(h5, live_recording(collector, centroids, poses, mounting=mounts))
    return live, stream, out, cal, h5, fused, centroids


def test_live_rows_equal_replay_of_its_recording_with_dropped_and_empty_slots(tmp_path, capsys):
    live, stream, out, cal, h5, _, centroids = _live(tmp_path, STREAM_CONFIG)
    again = tmp_path / "replay.jsonl"
    assert main(["replay", str(h5), "--calibration", str(cal), "-o", str(again),
                 "--summary"]) == 0
    capsys.readouterr()
    rows = {(r["frame"], r["id"]): [r["x_m"], r["y_m"], r["vx_mps"], r["vy_mps"],
                                    *np.ravel(r["covariance"])]
            for r in map(json.loads, out.read_text().splitlines())}
    replayed = {}
    for r in map(json.loads, again.read_text().splitlines()):
        for tid, x, p in zip(r["track_id"], r["track_state"], r["track_covariance"]):
            replayed[(r["frame"], tid)] = [*x, *np.ravel(p)]
    assert {k[0] for k in rows} & DROPPED_BY_ALL          # people through the dropped slots
    assert set(rows) == set(replayed)
    diff = max(np.abs(np.subtract(x, replayed[k])).max() for k, x in rows.items())
    assert diff <= 1e-9, diff
    assert live.fused == N and live.late == 0
    # Not pushed: the empty slots before the first centroid and those of the
    # long gap beyond max_misses (5); every other slot is, the dropped too.
    first = min(int(f) for f in centroids.detections("S1").frame)
    assert live.pushed == N - first - (len(EMPTY) - stream.tracker_config.max_misses)
    # The checks and the tracker at the boards' frame period (the motion
    # check carries each row by it), as replay takes the recording's.
    assert stream.tracker_config.frame_period_s == FRAME_PERIOD_S


def _replayed_rows(path):
    rows = {}
    for r in map(json.loads, path.read_text().splitlines()):
        for state, status, index in zip(r["state"], r["status"], r["detection_index"]):
            rows[(r["frame"], tuple(index))] = (int(status), np.asarray(state))
    return rows


def _differing(a, b):
    assert set(a) == set(b)
    return sorted(k for k in a if a[k][0] != b[k][0] or not np.allclose(
        a[k][1], b[k][1], rtol=0, atol=1e-9, equal_nan=True))


@pytest.mark.slow
def test_live_differs_from_fuse_only_where_the_stream_cannot_see_ahead(tmp_path, capsys):
    """``mmsnap fuse`` of live's recording decides each row with the frames
    after it too (the motion check's window); live, causal, from those before
    only. The rows that differ are exactly those that ``mmsnap replay
    --delay`` (the checks' look-around) gives as fuse does."""
    config = dataclasses.replace(STREAM_CONFIG, solve=FusionOptions(solver="vectorized"))
    *_, cal, h5, sink, _ = _live(tmp_path, config)
    live_rows = sink.rows
    fused = tmp_path / "fused.h5"
    assert main(["fuse", str(h5), "--calibration", str(cal), "--solver", "vectorized",
                 "-o", str(fused), "--no-progress"]) == 0
    f = read_fused(fused)
    offline = {(int(fr), tuple(int(i) for i in idx)): (int(st), np.asarray(x))
               for fr, idx, st, x in zip(f.frame, f.detection_index, f.status, f.state)}
    ahead = tmp_path / "ahead.jsonl"
    assert main(["replay", str(h5), "--calibration", str(cal), "--solver", "vectorized",
                 "--delay", str(config.context_frames), "-o", str(ahead), "--summary"]) == 0
    capsys.readouterr()
    differ = _differing(live_rows, offline)
    assert _differing(_replayed_rows(ahead), offline) == []
    ok = sum(1 for v in offline.values() if v[0] == 0)
    print(f"live vs fuse: {len(differ)} of {len(offline)} rows differ ({ok} fused ok by fuse): "
          f"{[(k[0], live_rows[k][0], offline[k][0]) for k in differ]}")
    # Each differing row is one the causal stream decided without the frames
    # after it: a frame of the check's window ahead holds rows.
    frames = sorted({k[0] for k in offline})
    for frame, _ in differ:
        assert any(frame < g <= frame + config.context_frames for g in frames)
