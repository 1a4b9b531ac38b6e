"""``mmsnap live`` on two emulated boards (real pseudo-terminals) playing a
simulated walk: people with ids as JSON lines, and ``mmsnap replay`` of the
recording ``--record`` wrote gives the same rows."""

from __future__ import annotations

import json

import numpy as np
import pytest

from mmsnap_graph.app.cli import main

from _boards import EmulatedBoard, Scene, board_packets, run_until_played
from _shared import ROOT, TI_DATA
from ti_samples import simulated

CFG = str(TI_DATA / "iwr1843_oob.cfg")
N = 60


@pytest.mark.slow
def test_live_prints_people_and_replay_of_its_recording_gives_the_same_rows(tmp_path, capsys):
    poses = simulated(N, seed=1).truth.node_poses
    cal = tmp_path / "cal.json"
    cal.write_text(json.dumps({"nodes": {n: {"pose": list(map(float, p))}
                                         for n, p in poses.items()}}))
    # One walk both boards look at: live configures S1, then S2 (about 1.5 s
    # later); S2 streams the walk from then on, as a real board would.
    scene = Scene()
    boards = {n: EmulatedBoard(board_packets(N, node=n, seed=1), scene=scene)
              for n in ("S1", "S2")}
    out, rec, view = tmp_path / "live.jsonl", tmp_path / "live.h5", tmp_path / "live.mcap"
    code, _, stderr = run_until_played(
        ["live", "--calibration", str(cal), "-o", str(out), "--record", str(rec),
         "--mount", "S1=0.8,5", "--mount", "S2=1.2,15", "--view-log", str(view)],
        boards, CFG, cwd=ROOT)
    assert code == 0, stderr
    rows = [json.loads(line) for line in out.read_text().splitlines()]
    assert rows and set(rows[0]) == {"frame", "time_s", "id", "x_m", "y_m", "vx_mps", "vy_mps",
                                     "covariance", "status"}
    assert all(r["status"] in ("tracked", "predicted") for r in rows)
    replayed = tmp_path / "replay.jsonl"
    capsys.readouterr()
    assert main(["replay", str(rec), "--calibration", str(cal), "-o", str(replayed),
                 "--summary"]) == 0
    # The covariance self-check: live says the verdict replay says.
    verdict = lambda err: [line.split(":", 1)[1].split(";")[0].strip()  # noqa: E731
                           for line in err.splitlines()
                           if line.startswith("covariance self-check (no truth):")]
    assert verdict(stderr) and verdict(stderr) == verdict(capsys.readouterr().err), stderr
    last = max(r["frame"] for r in rows)
    again = {}
    for line in replayed.read_text().splitlines():
        r = json.loads(line)
        for tid, x in zip(r["track_id"], r["track_state"]):
            again[(r["frame"], tid)] = x
    live = {(r["frame"], r["id"]): [r["x_m"], r["y_m"], r["vx_mps"], r["vy_mps"]] for r in rows}
    assert set(live) == {k for k in again if k[0] <= last}
    for key, x in live.items():
        np.testing.assert_allclose(x, again[key], rtol=0, atol=1e-9)
    _view_log_has_the_people(view, rows, boards=("S1", "S2"))


def _view_log_has_the_people(path, rows, boards):
    """The ``--view-log`` MCAP (read back with the mcap reader): each board's
    points, and per frame /persons holding the JSON lines' people."""
    pytest.importorskip("foxglove")
    from mcap.reader import make_reader

    topics, persons = set(), {}
    with open(path, "rb") as f:
        for _, channel, message in make_reader(f).iter_messages():
            topics.add(channel.topic)
            if channel.topic == "/persons":
                m = json.loads(message.data)
                persons[m["frame"]] = m["people"]
    assert {f"/points/{b}" for b in boards} | {"/radars", "/people", "/tracks"} <= topics
    got = [r for frame in sorted(persons) for r in persons[frame]]
    assert got == rows


@pytest.mark.slow
def test_live_refine_prints_and_stores_the_refined_poses(tmp_path):
    """``--refine`` on two emulated boards: the refinement process calibrates
    each window of the walk, its updates are JSON lines on standard error and
    the refined calibration JSON is written; the person rows still come."""
    from mmsnap_graph.io.calibration import read_calibration_json
    n = 400
    truth = simulated(n, seed=1, trajectory="random").truth.node_poses
    wrong = {k: np.asarray(p) + ([0.0, 0.0, 0.0] if k == "S1" else [0.05, -0.04, 0.02])
             for k, p in truth.items()}
    cal = tmp_path / "cal.json"
    cal.write_text(json.dumps({"nodes": {k: {"pose": list(map(float, p))}
                                         for k, p in wrong.items()}}))
    # One scene: a frame number is one instant on both boards, as real boards'
    # frames are (S2, configured later, streams the walk from then on).
    scene = Scene()
    boards = {k: EmulatedBoard(board_packets(n, node=k, seed=1, trajectory="random"),
                               scene=scene) for k in ("S1", "S2")}
    out, refined = tmp_path / "live.jsonl", tmp_path / "refined.json"
    code, _, stderr = run_until_played(
        ["live", "--calibration", str(cal), "-o", str(out), "--mount", "S1=0.8,5",
         "--mount", "S2=1.2,15", "--refine", "--refine-window-s", "8",
         "--refined-calibration", str(refined)],
        boards, CFG, cwd=ROOT)
    assert code == 0, stderr
    assert out.read_text().splitlines()
    updates = [json.loads(line) for line in stderr.splitlines() if line.startswith("{")]
    assert {u["type"] for u in updates} <= {"calibration", "self_check"}, stderr
    updates = [u for u in updates if u["type"] == "calibration"]
    assert updates, stderr
    windows = [u for u in updates if u["reason"] == "window"]
    assert windows, stderr
    stored = read_calibration_json(refined)
    np.testing.assert_allclose(stored.poses["S2"], windows[-1]["poses"]["S2"], atol=1e-9)
    err = lambda p: np.hypot(*(np.asarray(p[:2]) - truth["S2"][:2]))  # noqa: E731
    assert err(windows[-1]["poses"]["S2"]) < 0.5 * err(wrong["S2"]), stderr
