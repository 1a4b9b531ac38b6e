"""SimulationOptions: validated once, defaults (real physics, no cubes)."""

from __future__ import annotations

import inspect

import numpy as np
import pytest

from mmsnap_graph.errors import ConfigurationError, ValidationError
from mmsnap_graph.sim import (CLEAN, DEFAULT_LEVELS, RealPhysics, SimulationOptions,
                              simulate_recording)


def test_defaults_are_real_physics_and_no_cubes():
    assert SimulationOptions().physics == RealPhysics()
    assert CLEAN.physics is None and CLEAN.clean
    assert DEFAULT_LEVELS == ("centroids", "point_cloud")
    rec = simulate_recording("C", n_frames=5)
    node = rec.nodes["S1"]
    assert node.cube is None and node.centroids is not None and node.point_cloud is not None
    assert rec.metadata["model"] == "real"
    # The target model the calibration's defaults follow: bodies for the real
    # model, point targets for the clean one.
    assert rec.targets == "people"
    assert simulate_recording("C", options=CLEAN, n_frames=5).targets == "points"


def test_simulate_recording_takes_at_most_ten_parameters():
    assert len(inspect.signature(simulate_recording).parameters) <= 10


@pytest.mark.parametrize("kw, match", [
    (dict(frame_period_s=150.0), "milliseconds"),
    (dict(fov_rad=60.0), "degrees"),
    (dict(n_targets=0), "n_targets"),
    (dict(min_range_m=5.0, max_range_m=1.0), "min_range_m"),
    (dict(centroid_p_miss=1.0), "centroid_p_miss"),
])
def test_bad_values_name_the_field(kw, match):
    with pytest.raises(ValidationError, match=match):
        SimulationOptions(**kw)


def test_wrong_types_are_configuration_errors():
    with pytest.raises(ConfigurationError, match="physics"):
        SimulationOptions(physics="real")
    with pytest.raises(ValidationError, match="options must be a SimulationOptions"):
        simulate_recording("C", "straight", {"physics": None}, n_frames=5)
    with pytest.raises(ValidationError, match="p_miss"):
        RealPhysics(p_miss=1.0)
    with pytest.raises(ValidationError, match="room"):
        RealPhysics(room=(1.0, 0.0, 0.0, 3.0))
    with pytest.raises(TypeError):
        SimulationOptions(CLEAN)          # keyword-only


def test_cube_frames_sequence_is_frozen_as_a_tuple():
    opt = SimulationOptions(cube_frames=np.array([0, 2]))
    assert opt.cube_frames == (0, 2)
    rec = simulate_recording("C", options=opt, levels=("cube",), n_frames=4)
    assert list(rec.nodes["S1"].cube_frame) == [0, 2]
