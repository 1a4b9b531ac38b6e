"""Live frames in order and on one clock (mmsnap_graph.io.ti.serial.timing):
seeded arrival delays, restarts, corrupted numbers, clock drift."""

from __future__ import annotations

import numpy as np

from mmsnap_graph.io.ti.serial.timing import BoardClock, FrameSequence

T = 0.05


def _push(seq, numbers, times=None):
    times = [k * T for k in range(len(numbers))] if times is None else times
    return [seq.push(k, 0, bytes([i % 256, k % 256, k // 256 % 256]), t)
            for i, (k, t) in enumerate(zip(numbers, times))]


def test_copies_steps_back_and_corrupted_jumps_are_dropped_and_gaps_counted():
    seq = FrameSequence(T)
    out = _push(seq, [1, 2, 3, 2, 4, 2 ** 20 + 5, 6, 9, 10])
    assert [o is None for o in out] == [True, True, True, False, True, False, True, True, True]
    assert "goes back" in out[3] and "jumps ahead" in out[5]
    assert (seq.accepted, seq.dropped, seq.missing, seq.rejoins) == (7, 2, 3, 0)   # 5, 7, 8
    digest = b"same"
    assert seq.push(11, 0, digest, 0.5) is None
    assert "a copy" in seq.push(12, 0, digest, 0.55)


def test_a_board_that_restarts_is_followed_after_two_frames():
    seq = FrameSequence(T)
    out = _push(seq, [100, 101, 102, 1, 2, 3])
    assert [o is None for o in out] == [True, True, True, False, True, True]
    assert seq.rejoins == 1 and seq.rejoined is False


def test_slots_follow_the_counter_whatever_the_arrival_delays():
    """Arrivals delayed 0-40 ms (UART time, USB, a loaded host): the slots are
    the frame counter plus one offset, and two boards started 0.3 and 2.6
    frames apart land within half a frame of each other's grid."""
    rng = np.random.default_rng(0)
    k = np.arange(1, 401)
    slots = {}
    for name, start in (("A", 10.013), ("B", 10.013 + 2.6 * T)):
        clock = BoardClock(T, t0_s=10.0)
        delays = rng.exponential(0.01, k.size).clip(0, 0.04) + 0.002
        slots[name] = np.array([clock.slot(int(f), start + f * T + d)[0]
                                for f, d in zip(k, delays)])
        assert np.all(np.diff(slots[name]) == 1) and clock.reanchors == 0
    assert slots["B"][0] - slots["A"][0] == 3          # 2.6 frames later: slot + 3


def test_a_drifting_board_clock_is_re_anchored_without_two_frames_in_one_slot():
    clock = BoardClock(T, t0_s=0.0)
    drift = 1 + 2e-3                                    # 0.2 %: a frame every 500
    out = [clock.slot(f, f * T * drift + 0.003)[0] for f in range(1, 3001)]
    assert np.all(np.diff(out) >= 1) and clock.reanchors >= 4
    assert abs(out[-1] - 3000 * drift) <= 1
