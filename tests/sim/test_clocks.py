"""Simulated node clock offsets: :func:`mmsnap_graph.sim.clocks.offset_recording`
(the simulator's centroids, clean or real physics, each node sampled at its
own frame times)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from factors.models import measurement_model
from mmsnap_graph.data.noise import MeasurementNoise
from mmsnap_graph.errors import ValidationError
from mmsnap_graph.sim import CLEAN, SimulationOptions
from mmsnap_graph.sim.clocks import offset_recording

T = 0.15


def test_each_node_is_sampled_at_its_own_times():
    """Noise-free clean centroids: S2, 0.4 frame late, measures the walker
    where it is 0.4 frame after each reference frame (the truth between two
    frames, linearly: mm at 1 m/s), not where it is at the frame (cm)."""
    quiet = dataclasses.replace(CLEAN, centroid_noise=MeasurementNoise(
        range_m=1e-9, omega_rad=1e-9, doppler_mps=1e-9))
    rec = offset_recording("B", "straight", quiet, time_offsets_s={"S2": 0.4 * T},
                           n_frames=80, seed=3)
    frame, state = rec.truth.target(0)
    assert frame.tolist() == list(range(80)) and rec.frame_period_s == T
    pose = rec.truth.node_poses["S2"]
    det = rec.nodes["S2"].centroids
    k = det.frame[det.frame < 79]
    later = 0.6 * state[k] + 0.4 * state[k + 1]
    on_frame = measurement_model(state[k], pose)[0][:, 0]
    between = measurement_model(later, pose)[0][:, 0]
    got = det.range_m[det.frame < 79]
    assert np.median(np.abs(got - between)) < 0.005
    assert np.median(np.abs(got - on_frame)) > 0.03
    ref = rec.nodes["S1"].centroids
    np.testing.assert_allclose(ref.range_m, measurement_model(state[ref.frame],
                                                              rec.truth.node_poses["S1"])[0][:, 0],
                               atol=1e-6)
    np.testing.assert_allclose(rec.metadata["time_offsets_s"], [0.0, 0.4 * T])


def test_offset_recording_argument_errors():
    with pytest.raises(ValidationError, match="milliseconds"):
        offset_recording("B", time_offsets_s={"S2": 60.0}, n_frames=10)
    with pytest.raises(ValidationError, match="unknown nodes"):
        offset_recording("B", options=CLEAN, time_offsets_s={"S9": 0.1}, n_frames=10)
    with pytest.raises(ValidationError, match="SimulationOptions"):
        offset_recording("B", options="real", time_offsets_s={}, n_frames=10)


def test_real_physics_rows_come_from_the_fine_frames():
    """The real model's extra rows (clutter, splits, ghosts) stay on the
    node's frame numbers 0..n-1."""
    rec = offset_recording("B", "straight", SimulationOptions(), time_offsets_s={"S2": -1.3 * T},
                           n_frames=40, seed=1)
    for node in rec.nodes.values():
        f = node.centroids.frame
        assert f.min() >= 0 and f.max() <= 39
        assert np.unique(f).size > 30
