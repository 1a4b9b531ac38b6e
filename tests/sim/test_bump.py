"""A recording in which one radar is moved part-way (mmsnap_graph.sim.bump):
checked against the geometry (ranges are rotation-free) and against the
simulation without the bump."""

from __future__ import annotations

import numpy as np
import pytest

from mmsnap_graph.data.noise import MeasurementNoise
from mmsnap_graph.errors import ValidationError
from mmsnap_graph.sim import simulate_recording
from mmsnap_graph.sim.bump import BUMP_METADATA_KEYS, bumped_pose, simulate_bumped_recording
from mmsnap_graph.sim.networks import network_poses
from mmsnap_graph.sim.options import SimulationOptions

#: Noise far below every tolerance: the centroids are the geometry.
QUIET = MeasurementNoise(range_m=1e-9, omega_rad=1e-9, doppler_mps=1e-9)
BUMP = (0.3, -0.2, 0.05)
OPTIONS = dict(physics=None, centroid_noise=QUIET, centroid_p_miss=0.0)


@pytest.fixture(scope="module")
def bumped():
    return simulate_bumped_recording("C", "random", node="S2", bump=BUMP, bump_time_s=3.0,
                                     n_frames=60, seed=4, **OPTIONS)


def _ranges(det, truth, position):
    """(measured, geometric) ranges of one node's centroids to the target."""
    states = truth.state[np.searchsorted(truth.frame, det.frame)]
    return det.range_m, np.hypot(*(states[:, :2] - position[:2]).T)


def test_the_node_sees_from_its_old_pose_before_the_bump_and_its_new_one_after(bumped):
    frame = bumped.metadata["bump_frame"]
    assert frame == 20                                    # 3.0 s at 0.15 s a frame
    old = network_poses("C")["S2"]
    new = bumped_pose(old, BUMP)
    np.testing.assert_allclose(new, old + np.array(BUMP))
    det = bumped.nodes["S2"].centroids
    assert det.frame.min() < frame <= det.frame.max()
    got, from_old = _ranges(det, bumped.truth, old)
    _, from_new = _ranges(det, bumped.truth, new)
    before = det.frame < frame
    np.testing.assert_allclose(got[before], from_old[before], atol=1e-6)
    np.testing.assert_allclose(got[~before], from_new[~before], atol=1e-6)
    # the bump moved the ranges by centimetres: the two poses are told apart
    assert np.min(np.abs(from_new - from_old)) > 0.01


def test_the_other_nodes_truth_and_stated_poses_are_the_unbumped_simulations(bumped):
    plain = simulate_recording("C", "random", SimulationOptions(known_poses=True, **OPTIONS),
                               levels=("centroids",), n_frames=60, seed=4)
    np.testing.assert_array_equal(bumped.nodes["S1"].centroids.measurements,
                                  plain.nodes["S1"].centroids.measurements)
    np.testing.assert_array_equal(bumped.truth.state, plain.truth.state)
    for name in ("S1", "S2"):
        np.testing.assert_array_equal(bumped.truth.node_poses[name],
                                      plain.truth.node_poses[name])
        np.testing.assert_array_equal(bumped.nodes[name].pose, plain.nodes[name].pose)
    # S2 agrees with the plain run up to the bump, not after it
    mine, theirs = bumped.nodes["S2"].centroids, plain.nodes["S2"].centroids
    early = theirs.frame < 20
    np.testing.assert_array_equal(mine.measurements[mine.frame < 20], theirs.measurements[early])
    assert not np.allclose(mine.measurements[mine.frame >= 20], theirs.measurements[~early])


def test_the_metadata_says_which_node_moved_when_and_where(bumped):
    meta = bumped.metadata
    assert set(BUMP_METADATA_KEYS) <= set(meta)
    assert meta["bump_node"] == "S2" and meta["network"] == "C"
    assert meta["bump_time_s"] == pytest.approx(20 * 0.15)
    new = network_poses("C")["S2"] + np.array(BUMP)
    np.testing.assert_allclose([meta["bumped_x_m"], meta["bumped_y_m"], meta["bumped_phi_rad"]],
                               new)


def test_a_bump_time_between_frames_takes_the_next_frame():
    rec = simulate_bumped_recording("C", "straight", bump_time_s=1.01, n_frames=20, seed=1,
                                    **OPTIONS)
    assert rec.metadata["bump_frame"] == 7                # ceil(1.01 / 0.15)


@pytest.mark.parametrize("kwargs, match", [
    (dict(node="S9"), "node='S9' must be one of"),
    (dict(bump=(0.1, 0.0)), r"bump must be \(dx_m, dy_m, dphi_rad\)"),
    (dict(bump=(0.1, np.nan, 0.0)), "bump"),
    (dict(bump_time_s=0.0), "bump_time_s=0.0 must fall inside"),
    (dict(bump_time_s=100.0), "must fall inside the recording"),
    (dict(levels=("centroids",)), "centroid level only"),
])
def test_bad_arguments_are_named(kwargs, match):
    with pytest.raises(ValidationError, match=match):
        simulate_bumped_recording("C", "random", **{"n_frames": 40, **kwargs})
