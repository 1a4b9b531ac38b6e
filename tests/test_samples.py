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
from mmsnap_graph.io.ti.uart import parse_ti_uart

from _shared import DATA, TI_DATA
from ti_samples import main as make_samples, write_fast_sample

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
        # the simulator's clean model: point targets (no reflection depth;
        # before, the files did not say so and were read as people)
        assert a.targets == b.targets == "points"
        assert_array_equal(a.truth.state, b.truth.state)
        for name in a.node_names:
            for level in ("centroids", "point_cloud"):
                assert_allclose(getattr(a.nodes[name], level).measurements,
                                getattr(b.nodes[name], level).measurements,
                                rtol=1e-12, atol=1e-12)
            if a.nodes[name].cube is not None:
                # Float32 sums may round to a neighbouring ADC count on another BLAS.
                assert np.max(np.abs(a.nodes[name].cube - b.nodes[name].cube)) <= 1.5


def _csv_numbers(path):
    lines = path.read_text().splitlines()
    cells = [line.split(",") for line in lines[1:]]
    return lines[0], [c[0] for c in cells], np.array([c[1:] for c in cells], dtype=float)


def test_samples_are_what_the_script_makes(tmp_path):
    """The script makes the committed samples again, to their quantisation: the
    simulator's floats may differ in the last bit between NumPy/SciPy builds,
    which moves an int16 ADC count by one LSB or a CSV's sixth decimal by one."""
    make_samples(tmp_path)
    for name in ("dca1000_small.cfg", "dca1000_fast.cfg", "dca1000_fast.mmwave.json"):
        assert (tmp_path / name).read_text() == (TI_DATA / name).read_text(), name
    for name in ("dca1000_small.bin", "dca1000_fast.bin"):
        made = np.frombuffer((tmp_path / name).read_bytes(), dtype="<i2").astype(int)
        kept = np.frombuffer((TI_DATA / name).read_bytes(), dtype="<i2").astype(int)
        assert made.shape == kept.shape, name
        assert np.max(np.abs(made - kept)) <= 1, name          # one ADC count
        assert np.mean(made != kept) < 1e-3, name
    for name in ("points_sensor_frame.csv", "points_room_frame.csv"):
        head, nodes, values = _csv_numbers(tmp_path / name)
        head0, nodes0, values0 = _csv_numbers(TI_DATA / name)
        assert (head, nodes) == (head0, nodes0), name
        assert values.shape == values0.shape, name
        # the sixth decimal (relative for the 1.7e9 s time stamps)
        assert np.all(np.abs(values - values0) <= 1.5e-6 * np.maximum(1.0, np.abs(values0))), name
    for name in ("oob_uart_S1.bin", "oob_uart_S2.bin"):
        made = parse_ti_uart((tmp_path / name).read_bytes())
        kept = parse_ti_uart((TI_DATA / name).read_bytes())
        assert len((tmp_path / name).read_bytes()) == len((TI_DATA / name).read_bytes()), name
        assert made.points.frame.tolist() == kept.points.frame.tolist(), name
        np.testing.assert_allclose(made.points.points_xyz, kept.points.points_xyz, rtol=1e-6,
                                   atol=1e-6, err_msg=name)    # float32 on the wire
        np.testing.assert_allclose(made.points.snr_db, kept.points.snr_db, atol=0.11)


def test_the_fast_sample_is_what_the_script_makes(tmp_path):
    write_fast_sample(tmp_path)
    for name in ("dca1000_fast.cfg", "dca1000_fast.bin"):
        assert (tmp_path / name).read_bytes() == (TI_DATA / name).read_bytes(), name
