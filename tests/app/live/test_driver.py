"""The live driver (mmsnap_graph.app.live.driver) against ``mmsnap replay``
of the recording it makes: the same frames pushed, the same rows, whatever
slots the boards dropped (docs/LIVE.md, "Live and replay")."""

from __future__ import annotations

import json

import numpy as np

from mmsnap_graph.app.cli import main
from mmsnap_graph.app.live.driver import (LiveFusion, live_calibration, live_recording,
                                          live_stream)
from mmsnap_graph.app.live.sinks import CentroidLog, JsonLinesSink
from mmsnap_graph.fusion.stream.frame_stream import STREAM_CONFIG
from mmsnap_graph.io import write_recording
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


def test_live_rows_equal_replay_of_its_recording_with_dropped_and_empty_slots(tmp_path, capsys):
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
    stream = live_stream(names, live_poses, frame_period_s=FRAME_PERIOD_S, config=STREAM_CONFIG,
                         noise=stored.noise, pose_covariances=stored.pose_covariances,
                         range_offset_m=stored.range_offset_m)
    out = tmp_path / "live.jsonl"
    collector, centroids = FrameCollector(names, FRAME_PERIOD_S), CentroidLog()
    with open(out, "w", encoding="utf-8") as f:
        # t0 far ahead: no slot is overdue, each waits for every board (or the flush).
        live = LiveFusion(names, stream, mounting=mounts, frame_period_s=FRAME_PERIOD_S,
                          t0_s=1e12, sinks=[JsonLinesSink(f), centroids])
        for frame in _board_frames(rec):
            collector.add(frame)
            live.add(frame)
        live.flush()
    h5 = tmp_path / "live.h5"
    write_recording(h5, live_recording(collector, centroids, poses, mounting=mounts))
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
