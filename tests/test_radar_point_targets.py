"""Point targets and near-field leakage (issue 14, Build 6)."""

import numpy as np
import pytest

from mmsnap_graph.data.radar_config import TABLE_I
from mmsnap_graph.data.recording import Detections
from mmsnap_graph.errors import ConfigurationError
from mmsnap_graph.radar.chain import DEFAULT_MIN_RANGE_M, ChainConfig, process_cubes
from mmsnap_graph.radar.cluster import ClusterConfig, point_target_labels, torso_centroids
from mmsnap_graph.sim.cube import scatterer_amplitude, synthesize_cubes


def _reflector_cubes(n=12, seed=2, extra=None):
    """A corner reflector (10 m^2) walked slowly away at 6 m, 20 degrees off broadside;
    ``extra``: more scatterers ``(position (2,), velocity (2,), rcs)`` per frame."""
    rng = np.random.default_rng(seed)
    u = np.array([np.sin(0.35), np.cos(0.35)])
    pos, vel, amp = [], [], []
    for f in range(n):
        p = [(6.0 + 0.5 * f * TABLE_I.frame_period_s) * u]
        v = [0.5 * u]
        rcs = [10.0]
        for q, w, s in (extra or []):
            p.append(np.asarray(q, float))
            v.append(np.asarray(w, float))
            rcs.append(s)
        p = np.array(p)
        pos.append(p)
        vel.append(np.array(v))
        amp.append(scatterer_amplitude(TABLE_I, np.array(rcs), np.hypot(p[:, 0], p[:, 1])))
    return synthesize_cubes(TABLE_I, pos, vel, amp, rng=rng), u


def test_isolated_reflector_is_a_centroid_in_point_target_mode():
    cubes, u = _reflector_cubes()
    people = process_cubes(cubes, TABLE_I)
    points = process_cubes(cubes, TABLE_I, ChainConfig(cluster=ClusterConfig(point_targets=True)))
    # DBSCAN's three-point minimum drops the lone peak (issue 14: 32 of 101 frames) ...
    assert len(people.centroids) < len(cubes) // 2
    # ... the point-target mode gives it a centroid in every frame.
    assert np.unique(points.centroids.frame).size == len(cubes)
    t = np.arange(len(cubes)) * TABLE_I.frame_period_s
    first = np.array([np.flatnonzero(points.centroids.frame == f)[0] for f in range(len(cubes))])
    np.testing.assert_allclose(points.centroids.range_m[first], 6.0 + 0.5 * t, atol=0.03)
    np.testing.assert_allclose(points.centroids.omega_rad[first], np.pi * u[0], atol=0.05)
    np.testing.assert_allclose(points.centroids.doppler_mps[first], 0.5, atol=0.05)


def test_point_target_labels():
    labels = np.array([0, 0, 0, -1, -1, -1])
    snr = np.array([20.0, 20, 20, 30, 10, 16])
    cfg = ClusterConfig(point_targets=True, point_target_snr_db=15.0)
    np.testing.assert_array_equal(point_target_labels(labels, snr, cfg), [0, 0, 0, 1, -1, 2])
    np.testing.assert_array_equal(point_target_labels(labels, snr, ClusterConfig()), labels)
    np.testing.assert_array_equal(point_target_labels(labels, None, cfg), labels)
    # Through torso_centroids: one strong lone point, one weak one.
    cloud = Detections(frame=np.zeros(2, int), range_m=np.array([3.0, 6.0]),
                       omega_rad=np.array([0.0, 1.0]), doppler_mps=np.array([1.0, -1.0]),
                       snr_db=np.array([25.0, 5.0]))
    assert len(torso_centroids(cloud, ClusterConfig(), doppler_resolution_mps=0.18)) == 0
    out = torso_centroids(cloud, cfg, doppler_resolution_mps=0.18)
    np.testing.assert_allclose(out.measurements, [[3.0, 0.0, 1.0]], atol=1e-12)


@pytest.mark.parametrize("kwargs", [{"point_targets": "yes"}, {"point_targets": 1},
                                    {"point_target_snr_db": float("inf")}])
def test_point_target_options_are_checked(kwargs):
    with pytest.raises(ConfigurationError, match=next(iter(kwargs))):
        ClusterConfig(**kwargs)


def test_default_min_range_clears_near_field_residue():
    """A near-field residue (leakage through the radome that moves with the
    radar's own vibration, so clutter removal leaves it) at 0.72-0.78 m."""
    residue = [((0.02, 0.75), (0.0, 0.15), 1.0), ((-0.03, 0.72), (0.0, -0.1), 1.0)]
    cubes, _ = _reflector_cubes(n=8, seed=5, extra=residue)
    cfg = ClusterConfig(point_targets=True)
    old = process_cubes(cubes, TABLE_I, ChainConfig(min_range_m=0.3, cluster=cfg))
    new = process_cubes(cubes, TABLE_I, ChainConfig(cluster=cfg))
    assert DEFAULT_MIN_RANGE_M == ChainConfig().min_range_m == 0.9
    near_old = old.centroids.range_m < 0.85
    assert np.unique(old.centroids.frame[near_old]).size == len(cubes)  # false centroids
    assert new.point_cloud.range_m.min() >= 0.9 - TABLE_I.range_resolution_m
    assert np.all(new.centroids.range_m > 5.0)
    assert np.unique(new.centroids.frame).size == len(cubes)
