"""The one-node rows of a frame the association split
(mmsnap_graph.fusion.recording.split_check)."""

from __future__ import annotations

import numpy as np

from mmsnap_graph.data.results import Status
from mmsnap_graph.fusion.recording.split_check import split_rows, split_singles


# ------------------------------------------------------------------ split rows
def test_split_singles_are_the_one_node_groups_of_a_split_frame():
    frame = np.array([0, 1, 1, 2, 2, 3, 3, 3])
    idx = np.array([[0, 0],      # frame 0: one target, both nodes
                    [1, -1],     # frame 1: split, one detection each -> both flagged
                    [-1, 1],
                    [2, 2],      # frame 2: a pair and a second detection of S1 alone
                    [3, -1],     #   (S1 has two detections: two targets, not flagged)
                    [4, -1],     # frame 3: S1 two detections, S2 one: not flagged
                    [5, -1],
                    [-1, 3]])
    assert split_singles(frame, idx).tolist() == [False, True, True, False, False,
                                                  False, False, False]
    status = np.zeros(frame.size, np.int8)
    status[2] = Status.SINGULAR
    marked = split_rows(frame, idx, status)
    assert marked.tolist() == [False, True] + [False] * 6   # a failed row keeps its status
    assert not split_singles(np.zeros(0, int), np.zeros((0, 2), int)).any()


def test_a_sole_row_the_motion_check_kept_stays():
    # frame 1 split in two one-node rows; the motion check flagged one of them
    frame = np.array([1, 1])
    idx = np.array([[1, -1], [-1, 1]])
    status = np.array([Status.OK, Status.MOTION_INCONSISTENT], dtype=np.int8)
    assert split_rows(frame, idx, status).tolist() == [True, False]
    assert split_rows(frame, idx, status, keep_sole=True).tolist() == [False, False]
