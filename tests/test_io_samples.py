"""The sample recordings in data/: valid, consistent with their truth, and
what data/make_samples.py regenerates."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from factors.models import measurement_model, wrap_angle
from mmsnap_graph.io import read_recording
from mmsnap_graph.sim import CENTROID_NOISE, network_poses

from _shared import DATA

SAMPLES = sorted(DATA.glob("*.h5"))


def _load_make_samples():
    spec = importlib.util.spec_from_file_location("make_samples", DATA / "make_samples.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_samples_exist_and_are_small():
    names = {p.name for p in SAMPLES}
    assert {f"config_{c}_{t}.h5" for c in "ABC" for t in ("straight", "random")} <= names
    assert "cubes_B_random_4frames.h5" in names
    assert sum(p.stat().st_size for p in SAMPLES) < 12e6


@pytest.mark.parametrize("path", SAMPLES, ids=lambda p: p.name)
def test_sample_centroids_match_truth(path):
    rec = read_recording(path)
    config = path.name.split("_")[1]
    assert rec.node_names == ["S1", "S2"]
    n_f = len(np.unique(rec.truth.frame))
    states = rec.truth.state.reshape(-1, n_f, 4)
    for name, pose in network_poses(config).items():
        assert_allclose(rec.truth.node_poses[name], pose)
        c = rec.nodes[name].centroids
        h = measurement_model(states[c.target_id, c.frame], pose)[0]
        e = c.measurements - h
        e[:, 1] = wrap_angle(e[:, 1])
        assert np.all(np.abs(e) < 5 * CENTROID_NOISE.sigmas)
    if "cubes" in path.name:
        assert rec.nodes["S1"].cube.shape == (4, 512, 60, 12)


@pytest.mark.slow
def test_make_samples_regenerates_the_committed_files(tmp_path):
    written = _load_make_samples().make_samples(tmp_path)
    assert sorted(p.name for p in written) == [p.name for p in SAMPLES]
    for new in written:
        a, b = read_recording(DATA / new.name), read_recording(new)
        assert_array_equal(a.truth.state, b.truth.state)
        for name in a.node_names:
            for level in ("centroids", "point_cloud"):
                assert_allclose(getattr(a.nodes[name], level).measurements,
                                getattr(b.nodes[name], level).measurements,
                                rtol=1e-12, atol=1e-12)
            if a.nodes[name].cube is not None:
                # Float32 sums may round to a neighbouring ADC count on another BLAS.
                assert np.max(np.abs(a.nodes[name].cube - b.nodes[name].cube)) <= 1.5
