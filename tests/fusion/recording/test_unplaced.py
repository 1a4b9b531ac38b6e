"""The placement check (mmsnap_graph.fusion.recording.unplaced): one-node
rows that no walk ties to a row of two nodes are flagged; a walker who
leaves the other radar's view is not."""

from __future__ import annotations

import numpy as np

from mmsnap_graph.fusion.recording.unplaced import UNPLACED_LOOK_BACK_FRAMES, unplaced_rows

PERIOD_S = 0.05


def _rows(rng, k=200):
    """A walker at 1 m/s seen by both nodes for 60 frames, then by S1 alone;
    and a one-bounce image 6 m off, seen by S2 alone in frames 20-40."""
    f = np.arange(k)
    xy = np.c_[1.0 + 0.05 * f, np.full(k, 3.0)] + 0.05 * rng.standard_normal((k, 2))
    kept = np.zeros((k, 2), bool)
    kept[:, 0] = True
    kept[:60, 1] = True
    gf = np.arange(20, 41)
    gxy = np.c_[np.full(gf.size, -5.0), np.full(gf.size, 3.5)] + 0.05 * rng.standard_normal(
        (gf.size, 2))
    gkept = np.zeros((gf.size, 2), bool)
    gkept[:, 1] = True
    frame = np.r_[f, gf]
    order = np.argsort(frame, kind="stable")
    ghost = np.r_[np.zeros(k, bool), np.ones(gf.size, bool)][order]
    return (frame[order], np.r_[xy, gxy][order], np.r_[kept, gkept][order], ghost)


def test_an_image_seen_by_one_radar_is_flagged_and_the_walker_kept():
    frame, xy, kept, ghost = _rows(np.random.default_rng(0))
    ok = np.ones(frame.size, bool)
    flag = unplaced_rows(frame, xy, ok, kept, frame_period_s=PERIOD_S, body_m=0.5)
    assert flag[ghost].all()
    # The walker's one-node rows up to 5 s after his last two-node row (frame
    # 59) are tied by his walk; later nothing ties them.
    walker = ~ghost
    last = 59 + UNPLACED_LOOK_BACK_FRAMES
    assert not flag[walker & (frame <= last)].any()
    assert flag[walker & (frame > last)].all()


def test_a_gap_in_the_walk_or_a_failed_row_breaks_the_tie():
    frame, xy, kept, ghost = _rows(np.random.default_rng(1))
    ok = np.ones(frame.size, bool)
    ok[(frame >= 60) & (frame < 75) & ~ghost] = False      # 0.75 s without a row
    flag = unplaced_rows(frame, xy, ok, kept, frame_period_s=PERIOD_S, body_m=0.5)
    assert flag[~ghost & (frame >= 75) & (frame < 100)].all()
    assert not flag[~ok].any()                               # failed rows are not judged


def test_one_node_networks_and_empty_inputs_are_left_alone():
    frame = np.arange(10)
    xy = np.zeros((10, 2))
    assert not unplaced_rows(frame, xy, np.ones(10, bool), np.ones((10, 1), bool),
                             frame_period_s=PERIOD_S, body_m=0.5).any()
    assert unplaced_rows(frame[:0], xy[:0], np.ones(0, bool), np.ones((0, 2), bool),
                         frame_period_s=PERIOD_S, body_m=0.5).size == 0


def test_a_stream_judges_the_frames_it_decides_alone():
    frame, xy, kept, ghost = _rows(np.random.default_rng(2))
    ok = np.ones(frame.size, bool)
    whole = unplaced_rows(frame, xy, ok, kept, frame_period_s=PERIOD_S, body_m=0.5)
    one = unplaced_rows(frame, xy, ok, kept, frame_period_s=PERIOD_S, body_m=0.5,
                        decide=np.array([30]))
    assert np.array_equal(one, whole & (frame == 30)) and one.any()
