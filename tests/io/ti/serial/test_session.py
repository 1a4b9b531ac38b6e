"""The session's frame collector (mmsnap_graph.io.ti.serial.session): the
recording keeps each board's counter against its slots where that changes."""

from __future__ import annotations

import numpy as np

from mmsnap_graph.io import read_recording, write_recording
from mmsnap_graph.io.ti.point_cloud import Mounting
from mmsnap_graph.io.ti.serial.reader import BoardFrame
from mmsnap_graph.io.ti.serial.session import FrameCollector, board_frame_offsets


def _frame(board, slot, number):
    pts = {c: np.array([1.0]) for c in ("x", "y", "z", "doppler", "snr", "noise")}
    pts["y"] = np.array([2.0])
    return BoardFrame(board=board, slot=slot, frame_number=number, host_time_s=0.05 * slot,
                      start_s=0.05 * slot, points=pts)


def test_the_recording_keeps_each_change_of_a_boards_slot_offset(tmp_path):
    # S1's clock re-anchors at its frame 5 (slot 7 instead of 6), then its
    # counter restarts (frame 1 at slot 10); S2 runs one frame behind throughout.
    s1 = [(1, 2), (2, 3), (3, 4), (4, 5), (7, 5), (8, 6), (10, 1), (11, 2)]
    frames = [_frame("S1", s, k) for s, k in s1] + [_frame("S2", s, s - 1) for s in range(2, 9)]
    np.testing.assert_array_equal(board_frame_offsets(frames[:len(s1)]),
                                  [[1, -1], [7, 2], [10, 9]])
    collector = FrameCollector(["S1", "S2"], 0.05, t0_s=0.0)
    for f in frames:
        collector.add(f)
    rec = collector.recording(mounting={n: Mounting() for n in ("S1", "S2")})
    path = tmp_path / "rec.h5"
    write_recording(path, rec)
    md = read_recording(path, load_cubes=False).metadata
    np.testing.assert_array_equal(md["S1_board_frame_offsets"], [[1, -1], [7, 2], [10, 9]])
    np.testing.assert_array_equal(md["S2_board_frame_offsets"], [[2, 1]])
    assert md["S1_board_frame_offset"] == -1
