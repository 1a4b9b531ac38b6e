"""The emulated boards' shared scene (tests/_boards.py): boards that look at
one walk stream the same moment of it at the same host time, whenever each
was started."""

from __future__ import annotations

import math

from _boards import EmulatedBoard, Scene, wait_for

PERIOD_S = 0.05


def test_a_board_started_later_streams_the_scene_from_then_on():
    scene = Scene()
    packets = [bytes([i]) * 8 for i in range(12)]
    with EmulatedBoard(packets, cli=False, frame_period_s=PERIOD_S, scene=scene) as first, \
            EmulatedBoard(packets, cli=False, frame_period_s=PERIOD_S, scene=scene,
                          start_delay_s=0.2) as late:
        wait_for(lambda: first.done.is_set() and late.done.is_set(), "the boards to play",
                 timeout_s=30)
        assert first.first_packet == 0 and len(first.write_times) == len(packets)
        # Started 0.2 s (4 frames) after the scene: the packets of that past are lost ...
        assert late.first_packet >= 4
        assert len(late.write_times) == len(packets) - late.first_packet
        # ... and packet i goes out at the scene's time i * period on both boards.
        for board in (first, late):
            for i, t in zip(range(board.first_packet, len(packets)), board.write_times):
                assert t >= scene.start + i * PERIOD_S
        sent_at = {i: t for i, t in zip(range(late.first_packet, len(packets)),
                                        late.write_times)}
        for i, t in enumerate(first.write_times):
            if i in sent_at:
                # Same scene frame, same host time (within the writes' scheduling).
                assert math.isclose(sent_at[i], t, abs_tol=3 * PERIOD_S)


def test_boards_without_a_scene_play_from_their_own_start():
    packets = [bytes([i]) * 8 for i in range(4)]
    with EmulatedBoard(packets, cli=False, frame_period_s=PERIOD_S, start_delay_s=0.1) as b:
        wait_for(b.done.is_set, "the board to play", timeout_s=30)
        assert b.first_packet == 0 and len(b.write_times) == len(packets)


def test_a_board_of_a_scene_with_a_phase_writes_that_much_later():
    scene = Scene()
    packets = [bytes([i]) * 8 for i in range(6)]
    with EmulatedBoard(packets, cli=False, frame_period_s=PERIOD_S, scene=scene) as first, \
            EmulatedBoard(packets, cli=False, frame_period_s=PERIOD_S, scene=scene,
                          phase_s=0.6 * PERIOD_S) as later:
        wait_for(lambda: first.done.is_set() and later.done.is_set(), "the boards to play",
                 timeout_s=30)
        assert later.first_packet == 0 and len(later.write_times) == len(packets)
        for i, t in enumerate(later.write_times):
            assert t >= scene.start + (i + 0.6) * PERIOD_S
