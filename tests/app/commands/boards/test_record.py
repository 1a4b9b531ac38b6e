"""``mmsnap record`` on emulated boards (real pseudo-terminals, tests/_boards.py):
four boards, one with a damaged stream, one that starts late, one that stops,
one in the 3D People Tracking format, recorded on one clock and ended by
Ctrl-C; the CLI errors a board can give; boards that only stream."""

from __future__ import annotations

import pytest

from mmsnap_graph.app.cli import main
from mmsnap_graph.io import read_recording

from _boards import EmulatedBoard, board_packets, damage, run_until_played
from _shared import ROOT, TI_DATA

CFG = str(TI_DATA / "iwr1843_oob.cfg")
N = 40


@pytest.mark.slow
def test_four_boards_on_one_clock_until_ctrl_c(tmp_path):
    clean = board_packets(N, node="S1", seed=1)
    damaged, lost = damage(board_packets(N, node="S2", seed=1), seed=3)
    tracking = board_packets(N, node="S1", seed=2, demo="tracking")
    stopping = board_packets(N, node="S2", seed=2)
    boards = {"S1": EmulatedBoard(clean), "S2": EmulatedBoard(damaged),
              "S3": EmulatedBoard(tracking, start_delay_s=0.6),
              "S4": EmulatedBoard(stopping, stop_after=15, garbled_first=False)}
    out = tmp_path / "rec.h5"
    code, stdout, stderr = run_until_played(
        ["record", "-o", str(out), "--mount", "S1=0.8,5", "--mount", "S2=1.2,15",
         "--mount", "S3=0.8,5", "--mount", "S4=1.2,15"],
        boards, CFG, cwd=ROOT)
    assert code == 0, stderr
    assert "stopped after Ctrl-C" in stdout
    rec = read_recording(out)
    md = rec.metadata
    assert md["source"] == "ti-live" and md["frame_clock"] == "host"
    frames = {name: md[f"{name}_frames"] for name in boards}
    assert frames == {"S1": N, "S2": N - len(lost), "S3": N, "S4": 15}
    assert md["S2_bad_packets"] == len(lost) > 0 and md["S1_bad_packets"] == 0
    assert md["S3_demo"] == "tracking" and md["S1_demo"] == "oob"
    # Every board sent its cfg between sensorStop/flushCfg and sensorStart, once each.
    for b in boards.values():
        assert b.commands[:2] == ["sensorStop", "flushCfg"] and b.commands[-1] == "sensorStop"
        assert b.commands.count("sensorStart") == 1
    # One clock: slot = board frame + offset. A board's first frame takes the
    # slot of its start on the host clock, rounded to the grid from slot 0
    # (host_t0_s); later frames follow its counter. So the offset is the first
    # frame's start (its write here) within half a frame, plus the read's
    # delay (up to half a frame on a loaded machine). (Was: two boards'
    # offsets against their mean starts within 0.8 frame, which the two
    # roundings and the write jitter exceed now and then.)
    period, t0 = rec.frame_period_s, md["host_t0_s"]
    started = {n: b.write_times[0] / period - 1 for n, b in boards.items()}   # frame 1 first
    offsets = {n: md[f"{n}_board_frame_offset"] for n in boards}
    for n in boards:
        assert md[f"{n}_clock_reanchors"] == 0
        assert -0.5 - 1e-9 <= offsets[n] - (started[n] - t0 / period) <= 0.5 + 0.5, (
            offsets, started, t0 / period)
    assert offsets["S3"] - offsets["S1"] >= 0.6 / period - 2       # started 0.6 s later


def test_a_refused_cfg_line_names_the_board_the_line_and_the_reply(tmp_path, capsys):
    out = tmp_path / "r.h5"
    with EmulatedBoard([], refuse={"frameCfg"}) as b:
        code = main(["record", "--board", f"S1={b.cli_port},{b.data_port},{CFG}", "-o", str(out)])
    assert code == 2 and not out.exists()
    assert ("board S1: line 12 'frameCfg 0 2 16 0 50 1 0': the board replied 'Error -1'"
            in capsys.readouterr().err)


def test_a_board_that_only_streams_recorded_for_a_duration(tmp_path, capsys):
    out = tmp_path / "r.h5"
    with EmulatedBoard(board_packets(10), cli=False, start_delay_s=0.3) as b:
        assert main(["record", "--board", f"S1=,{b.data_port}", "--no-send-cfg",
                     "--frame-period", "0.05", "--duration", "2.5", "-o", str(out)]) == 0
        assert b.done.is_set()
    rec = read_recording(out)
    assert rec.metadata["S1_frames"] == 10 and len(rec.nodes["S1"].point_cloud) > 0
    assert "stopped after 2.5 s" in capsys.readouterr().out
