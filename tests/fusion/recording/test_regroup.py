"""One centroid per body before the association (:mod:`mmsnap_graph.fusion.recording.regroup`)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from _shared import POSES_BC
from mmsnap_graph.fusion.options import FusionOptions
from mmsnap_graph.fusion.recording.regroup import merge_body_detections
from mmsnap_graph.fusion.recording.sequence import fuse_recording
from mmsnap_graph.sim import SimulationOptions, simulate_recording
from mmsnap_graph.sim.real.ghosts import ghost_centroids
from mmsnap_graph.sim.simulator import CENTROID_NOISE
from _fusion import config


def _meas(xy, doppler):
    xy = np.asarray(xy, dtype=float)
    r = np.hypot(xy[:, 0], xy[:, 1])
    return np.column_stack([r, np.pi * xy[:, 0] / r, doppler])


def test_two_halves_of_a_body_become_their_mean_and_distant_ones_stay():
    # Frame 0: halves 0.5 m apart around (0.3, 3); frame 1: two people 1 m apart;
    # frame 2: three clusters chained 0.4 m apart (one body, single linkage).
    xy = [(0.05, 3.0), (0.55, 3.0), (0.0, 3.0), (1.0, 3.0), (0.0, 4.0), (0.4, 4.0), (0.8, 4.0)]
    frame = np.array([0, 0, 1, 1, 2, 2, 2])
    meas = _meas(xy, [0.5, 0.7, 0.1, 0.2, 1.0, 1.0, 1.3])
    keep, merged = merge_body_detections(frame, meas, 0.6)
    np.testing.assert_array_equal(keep, [True, False, True, True, True, False, False])
    np.testing.assert_allclose(merged[0], _meas([(0.3, 3.0)], 0.6)[0])
    np.testing.assert_allclose(merged[2:4], meas[2:4])
    np.testing.assert_allclose(merged[4], _meas([(0.4, 4.0)], 1.1)[0])


@pytest.mark.parametrize("fraction", [0.2])
def test_a_split_body_fuses_as_the_whole_one(fraction):
    """Split clusters (each centroid replaced by two 0.3-0.6 m apart around
    it) fuse to the clean rows once merged; unmerged, a half kept in a row
    biases it."""
    net = {"S1": POSES_BC[0], "S2": POSES_BC[1], "S3": POSES_BC[2]}
    rec = simulate_recording(net, "random", SimulationOptions(physics=None, known_poses=True),
                             levels=("centroids",), n_frames=150, seed=4)
    split = ghost_centroids(rec, "split", fraction, seed=5)
    clean = fuse_recording(rec, config(robust="gate"), noise=CENTROID_NOISE, progress=False)
    merged = fuse_recording(split, config(robust="gate"), noise=CENTROID_NOISE, progress=False)
    raw = fuse_recording(split, config(robust="gate", body_merge=False), noise=CENTROID_NOISE, progress=False)
    np.testing.assert_array_equal(merged.frame, clean.frame)
    np.testing.assert_allclose(merged.state[merged.success], clean.state[clean.success],
                               atol=1e-6)
    err = raw.state[raw.success, :2] - rec.truth.state[raw.frame[raw.success], :2]
    err0 = clean.state[clean.success, :2] - rec.truth.state[clean.frame[clean.success], :2]
    assert np.sqrt(np.mean(np.sum(err ** 2, 1))) > 1.2 * np.sqrt(np.mean(np.sum(err0 ** 2, 1)))


def test_merge_body_m_is_validated():
    from mmsnap_graph.errors import ValidationError
    from mmsnap_graph.fusion.config import AssociationOptions

    for bad in (0, -0.5, float("nan"), True, "0.5"):
        with pytest.raises(ValidationError, match="merge_body_m"):
            AssociationOptions(merge_body_m=bad)
    assert AssociationOptions(merge_body_m=0.4).merge_body_m == 0.4
    assert AssociationOptions(merge_body_m=None).merge_body_m is None


def test_plain_fusion_does_not_merge_unless_told():
    """Without a robust option (the library's default) nothing is merged."""
    net = {"S1": POSES_BC[0], "S2": POSES_BC[1], "S3": POSES_BC[2]}
    rec = simulate_recording(net, "random", SimulationOptions(physics=None, known_poses=True),
                             levels=("centroids",), n_frames=60, seed=4)
    split = ghost_centroids(rec, "split", 0.3, seed=5)
    plain = fuse_recording(split, config(), noise=CENTROID_NOISE, progress=False)
    told = fuse_recording(split, config(body_merge=True), noise=CENTROID_NOISE, progress=False)
    assert len(told) == len(fuse_recording(rec, config(), noise=CENTROID_NOISE, progress=False))
    assert len(plain) > len(told)
