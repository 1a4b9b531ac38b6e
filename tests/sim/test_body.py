"""The walking human as point scatterers (mmsnap_graph.sim.body)."""

from __future__ import annotations

from numpy.testing import assert_allclose
import numpy as np
import pytest

from mmsnap_graph.sim.body import ARM, HumanBody, LEG, TORSO, body_scatterers
from mmsnap_graph.sim.networks import COMMON_AREAS
from mmsnap_graph import ValidationError
from mmsnap_graph.sim.trajectories import RandomWalkOptions, random_walk


def test_body_torso_centroid_and_limb_doppler_spread():
    area = COMMON_AREAS["B"]
    s = random_walk(area, seed=0)
    b = body_scatterers(s, 0.15, rng=np.random.default_rng(0))
    part = b.part
    assert b.positions_m.shape == (600, HumanBody().n_scatterers, 2)
    assert set(part.tolist()) == {TORSO, ARM, LEG}
    # Truth tracks the torso: its points are centred on the state.
    assert_allclose(b.positions_m[:, part == TORSO].mean(axis=1), s[:, :2], atol=1e-12)
    rel = np.linalg.norm(b.velocities_mps - s[:, None, 2:], axis=-1)
    # Feet swing up to 2-3 times walking speed; arms less; the torso barely
    # (it only turns).
    assert 1.5 < rel[:, part == LEG].max() < 4.0
    assert 0.5 < rel[:, part == ARM].max() < rel[:, part == LEG].max()
    # (Torso points are at most 0.18 m from the centre; turns reach ~5 rad/s.)
    assert rel[:, part == TORSO].max() < 1.0
    assert np.median(rel[:, part == TORSO]) < 0.3
    # Limbs stay within reach of the torso.
    reach = np.linalg.norm(b.positions_m - s[:, None, :2], axis=-1)
    assert reach.max() < 0.9
    # Torso carries most of the RCS.
    assert b.rcs_m2[part == TORSO].sum() == pytest.approx(HumanBody().torso_rcs_m2)


def test_body_velocities_are_derivatives_of_positions():
    s = random_walk(COMMON_AREAS["B"], frame_period_s=0.002, n_frames=3000, seed=1,
                    options=RandomWalkOptions(substeps=1))
    b = body_scatterers(s, 0.002)
    fd = (b.positions_m[2:] - b.positions_m[:-2]) / 0.004
    assert np.abs(fd - b.velocities_mps[1:-1]).max() < 0.05


def test_standing_body_has_still_limbs():
    s = np.tile([1.0, 3.0, 0.0, 0.0], (20, 1))
    b = body_scatterers(s, 0.15, rng=np.random.default_rng(2))
    assert_allclose(b.velocities_mps, 0.0, atol=1e-12)
    assert_allclose(b.positions_m, np.broadcast_to(b.positions_m[0], b.positions_m.shape), atol=1e-12)
    with pytest.raises(ValidationError, match=r"states must have shape \(F, 4\)"):
        body_scatterers(np.zeros((3, 2)), 0.15)
    with pytest.raises(ValidationError, match="n_torso=3"):
        HumanBody(n_torso=3)
