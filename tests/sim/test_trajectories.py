"""Torso trajectories (mmsnap_graph.sim.trajectories): random walks and straight lines."""

from __future__ import annotations

from numpy.testing import assert_allclose
import numpy as np
import pytest

from mmsnap_graph.sim.networks import COMMON_AREAS
from mmsnap_graph import ValidationError
from mmsnap_graph.sim import SimulationOptions
from mmsnap_graph.sim.trajectories import (RandomWalkOptions, make_trajectory, random_walk,
                                           straight_line)


def _check_walk(states, area, frame_period_s):
    assert area.contains(states[:, :2]).all()
    # Velocity is the derivative of the position (trapezoid over one frame).
    chord = np.diff(states[:, :2], axis=0) / frame_period_s
    mean_v = 0.5 * (states[1:, 2:] + states[:-1, 2:])
    assert np.max(np.linalg.norm(chord - mean_v, axis=1)) < 0.15


@pytest.mark.parametrize("name", ["A", "B", "C"])
def test_random_walk_stays_inside_at_human_speed(name):
    area = COMMON_AREAS[name]
    s = random_walk(area, seed=3)
    assert s.shape == (600, 4)
    _check_walk(s, area, 0.15)
    speed = np.hypot(s[:, 2], s[:, 3])
    assert speed.min() >= 0.5 - 1e-9 and speed.max() <= 1.5 + 1e-9
    assert 0.8 < speed.mean() < 1.2
    # It explores the area rather than circling in one spot.
    assert np.ptp(s[:, 0]) > 0.5 * area.size_m[0] and np.ptp(s[:, 1]) > 0.5 * area.size_m[1]
    assert_allclose(random_walk(area, seed=3), s)  # seeded


def test_straight_line_paces_back_and_forth():
    area = COMMON_AREAS["C"]
    s = straight_line(area, start_m=[-1, 3], end_m=[1, 3], speed_mps=1.2)
    _check_walk(s, area, 0.15)
    assert_allclose(s[:, 1], 3.0)
    assert_allclose(s[:, 3], 0.0)
    assert s[:, 0].min() >= -1 - 1e-9 and s[:, 0].max() <= 1 + 1e-9
    assert np.abs(s[:, 2]).max() == pytest.approx(1.2)
    # 90 s over a 2 m segment at 1.2 m/s with turns: about 40 reversals.
    reversals = np.sum(np.diff(np.sign(s[np.abs(s[:, 2]) > 0.1, 2])) != 0)
    assert 30 <= reversals <= 50
    with pytest.raises(ValidationError, match="speed_mps=5"):
        straight_line(area, speed_mps=5)
    with pytest.raises(ValidationError, match="kind='zigzag'"):
        make_trajectory("zigzag", area)
    with pytest.raises(ValidationError, match="n_frames=0"):
        random_walk(area, n_frames=0)


def test_random_walk_options_are_validated_once_with_units():
    with pytest.raises(ValidationError, match="max_speed_mps=5"):
        RandomWalkOptions(max_speed_mps=5)
    with pytest.raises(ValidationError, match="turn_tau_s=0"):
        RandomWalkOptions(turn_tau_s=0)
    with pytest.raises(ValidationError, match="substeps"):
        RandomWalkOptions(substeps=0)
    with pytest.raises(ValidationError, match="RandomWalkOptions"):
        random_walk(COMMON_AREAS["B"], options={"substeps": 1})


def test_random_walk_options_tune_the_walk():
    area = COMMON_AREAS["B"]
    slow = random_walk(area, seed=3, options=RandomWalkOptions(
        mean_speed_mps=0.6, min_speed_mps=0.5, max_speed_mps=0.7))
    speed = np.hypot(slow[:, 2], slow[:, 3])
    assert 0.5 - 1e-9 <= speed.min() and speed.max() <= 0.7 + 1e-9
    # Through the dispatcher and the simulator's options, the same object.
    assert_allclose(make_trajectory("random", area, seed=3, walk=RandomWalkOptions()),
                    random_walk(area, seed=3))
    with pytest.raises(ValidationError, match="'straight'"):
        make_trajectory("straight", area, walk=RandomWalkOptions())
    with pytest.raises(ValidationError, match="RandomWalkOptions"):
        SimulationOptions(trajectory_options={"substeps": 1})
