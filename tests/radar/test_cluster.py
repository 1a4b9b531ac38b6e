"""The chain's small-cloud DBSCAN against scikit-learn's (the reference)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from sklearn.cluster import DBSCAN

from mmsnap_graph.radar.cluster import dbscan_small


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
