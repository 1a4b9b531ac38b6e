"""The noise estimators' screens: single-target sequences and the ghosts in
them (:mod:`mmsnap_graph.calibration.noise.sequences`)."""

from __future__ import annotations

import numpy as np

from mmsnap_graph.calibration.noise.sequences import (
    GHOST_REACH, ghost_rows, single_target_sequences)
from mmsnap_graph.data.recording import Detections


def _walk(n: int, seed: int = 0, frame=None, target_id=None) -> Detections:
    """A smooth walk (range, omega, Doppler) with small white noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(n, dtype=float)
    return Detections(frame=np.arange(n) if frame is None else np.asarray(frame),
                      range_m=3.0 + 0.02 * t + rng.normal(0, 0.01, n),
                      omega_rad=0.2 + 0.005 * t + rng.normal(0, 0.005, n),
                      doppler_mps=0.4 + rng.normal(0, 0.02, n),
                      target_id=target_id)


def test_unlabelled_rows_keep_only_the_frames_with_one_centroid():
    frame = np.array([0, 1, 1, 2, 3, 3, 3, 4])
    det = _walk(frame.size, frame=frame)
    (rows,) = single_target_sequences(det)
    assert sorted(det.frame[rows].tolist()) == [0, 2, 4]


def test_labelled_rows_give_one_sequence_per_target():
    frame = np.array([0, 0, 1, 1, 2, 2, 2])
    labels = np.array([5, 7, 7, 5, 5, 7, 7])     # target 7 twice in frame 2
    det = _walk(frame.size, frame=frame, target_id=labels)
    seqs = single_target_sequences(det)
    assert len(seqs) == 2
    by_target = {int(labels[s[0]]): det.frame[s].tolist() for s in seqs}
    assert by_target == {5: [0, 1, 2], 7: [0, 1]}


def test_a_spike_in_a_smooth_sequence_is_a_ghost_and_nothing_else_is():
    det = _walk(60, seed=1)
    clean = ghost_rows(det)
    assert not clean.any()
    spiked = Detections(frame=det.frame, range_m=det.range_m.copy(),
                        omega_rad=det.omega_rad, doppler_mps=det.doppler_mps)
    spiked.range_m[30] += 1.5                   # a ghost 1.5 m behind the walker
    flags = ghost_rows(spiked)
    assert flags.tolist() == [i == 30 for i in range(60)]


def test_the_ends_of_a_sequence_are_never_flagged():
    det = _walk(40, seed=2)
    det.range_m[0] += 2.0
    det.range_m[-1] += 2.0
    det.range_m[GHOST_REACH] += 2.0              # the first row with neighbours on both sides
    flags = ghost_rows(det)
    assert not flags[0] and not flags[-1] and flags[GHOST_REACH]


def test_a_sequence_too_short_for_the_predictions_is_left_alone():
    det = _walk(2 * GHOST_REACH, seed=3)
    det.range_m[GHOST_REACH] += 5.0
    assert not ghost_rows(det).any()
