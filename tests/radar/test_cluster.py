"""The chain's small-cloud DBSCAN against scikit-learn's (the reference)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from sklearn.cluster import DBSCAN

from mmsnap_graph.radar.cluster import (
    dbscan_small,
    ClusterConfig,
    torso_centroids,
    point_target_labels,
)
from mmsnap_graph.data.recording import Detections
from mmsnap_graph.errors import ConfigurationError


def _reference(feats, eps, min_samples):
    return DBSCAN(eps=eps, min_samples=min_samples).fit_predict(feats)


@pytest.mark.parametrize("seed", range(25))
def test_matches_sklearn_on_clustered_clouds(seed):
    rng = np.random.default_rng(seed)
    # A few blobs (people), scattered clutter, and chains of points that
    # join blobs through border points: the hard cases for labelling order.
    blobs = [rng.normal(rng.uniform(-5, 5, 2), rng.uniform(0.05, 0.4), (rng.integers(1, 15), 2))
             for _ in range(rng.integers(0, 4))]
    clutter = rng.uniform(-6, 6, (rng.integers(0, 20), 2))
    chain = np.cumsum(rng.normal(0, 0.3, (rng.integers(0, 12), 2)), axis=0)
    feats = np.concatenate(blobs + [clutter, chain, np.zeros((0, 2))])
    feats = feats[rng.permutation(len(feats))]
    for eps, ms in ((0.4, 3), (0.3, 1), (0.8, 5), (0.25, 2)):
        np.testing.assert_array_equal(dbscan_small(feats, eps, ms), _reference(feats, eps, ms)
                                      if len(feats) else np.zeros(0, int))


@settings(max_examples=120, deadline=None)
@given(st.lists(st.tuples(st.integers(-8, 8), st.integers(-8, 8)), max_size=40),
       st.integers(1, 6))
def test_matches_sklearn_on_grids(points, min_samples):
    """Points on a 0.25 m grid: many ties at exactly eps (neighbours
    included), duplicates, lone points."""
    feats = np.asarray(points, dtype=float).reshape(-1, 2) * 0.25
    got = dbscan_small(feats, 0.5, min_samples)
    want = _reference(feats, 0.5, min_samples) if len(feats) else np.zeros(0, int)
    np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("cluster", [ClusterConfig(), ClusterConfig(point_targets=True),
                                     ClusterConfig(method="mean", min_samples=2)])
@pytest.mark.parametrize("with_snr", [True, False])
def test_torso_centroids_of_many_frames_equal_frame_by_frame(cluster, with_snr):
    rng = np.random.default_rng(8)
    n_frames = 30
    sizes = rng.integers(0, 9, n_frames)
    frame = np.repeat(np.arange(n_frames) * 3 + 5, sizes)
    k = frame.size
    centre = rng.uniform(2, 8, n_frames).repeat(sizes)
    cloud = Detections(frame=frame,
                       range_m=centre + rng.normal(0, 0.2, k),
                       omega_rad=rng.normal(0.2, 0.15, k),
                       doppler_mps=rng.normal(1.0, 0.3, k),
                       snr_db=rng.uniform(5, 25, k) if with_snr else None)
    shuffled = rng.permutation(k)  # frames need not be sorted
    cloud = Detections(frame=cloud.frame[shuffled], range_m=cloud.range_m[shuffled],
                       omega_rad=cloud.omega_rad[shuffled],
                       doppler_mps=cloud.doppler_mps[shuffled],
                       snr_db=None if cloud.snr_db is None else cloud.snr_db[shuffled])
    res = 0.1
    together = torso_centroids(cloud, cluster, doppler_resolution_mps=res)
    parts = []
    for f in np.unique(cloud.frame):
        m = np.flatnonzero(cloud.frame == f)
        one = Detections(frame=cloud.frame[m], range_m=cloud.range_m[m],
                         omega_rad=cloud.omega_rad[m], doppler_mps=cloud.doppler_mps[m],
                         snr_db=None if cloud.snr_db is None else cloud.snr_db[m])
        parts.append(torso_centroids(one, cluster, doppler_resolution_mps=res))
    assert len(together) > 5
    for name in ("frame", "range_m", "omega_rad", "doppler_mps", "snr_db"):
        want = np.concatenate([getattr(d, name) for d in parts if len(d)])
        np.testing.assert_array_equal(getattr(together, name), want)


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
