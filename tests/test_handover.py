"""Hand-over to trackers: ``/fused`` carries time stamps and the prior-free
information form; ``mmsnap evaluate`` says when the NEES check fails."""

from __future__ import annotations

import dataclasses
import json

import h5py
import numpy as np
import pytest

from factors.models import measurement_model
from mmsnap_graph.fusion import FusionOptions
from mmsnap_graph.app.cli import main
from mmsnap_graph.app.evaluation import evaluate_recording, failed_checks
from mmsnap_graph.data.noise import GaussianPrior
from mmsnap_graph.data.results import measurement_information
from mmsnap_graph.fusion.recording.sequence import fuse_recording
from mmsnap_graph.io import write_fused, write_recording
from mmsnap_graph.io.fused import read_fused
from mmsnap_graph.sim import simulate_recording
from mmsnap_graph.sim import SimulationOptions


@pytest.fixture(scope="module")
def recording():
    return simulate_recording("B", "random", SimulationOptions(physics=None, known_poses=True),
                              levels=("centroids",), n_frames=60, seed=5)


@pytest.fixture(scope="module")
def fused_map(recording):
    return fuse_recording(recording, progress=False)


@pytest.fixture(scope="module")
def fused_ml(recording):
    return fuse_recording(recording, mode="ml", prior=None, progress=False)


def _jtwj(fused, i):
    """J^T W J of row ``i`` at its estimate, from the measurement model."""
    w = np.diag(1.0 / fused.noise_sigmas**2)
    out = np.zeros((4, 4))
    for n in np.flatnonzero(fused.observed[i] & ~fused.rejected[i]):
        _, jac = measurement_model(fused.state[i], fused.node_poses[n])
        out += jac.T @ w @ jac
    return out


@pytest.mark.parametrize("which", ["fused_map", "fused_ml"])
@pytest.mark.parametrize("solver", ["vectorized", "gtsam"])
def test_information_is_jtwj_at_the_estimate(which, solver, recording, request):
    fused = request.getfixturevalue(which)
    if solver == "gtsam":
        kw = {} if fused.mode == "map" else {"mode": "ml", "prior": None}
        fused = fuse_recording(recording,
                               progress=False,
                               **kw,
                               options=FusionOptions(solver="gtsam"))
    rows = np.flatnonzero(fused.success)
    assert rows.size > 50
    for i in rows:
        expect = _jtwj(fused, i)
        # Measured: relative errors ~1e-14 (the Laplace covariance is the
        # inverse Gauss-Newton information at the estimate).
        np.testing.assert_allclose(fused.information[i], expect, rtol=1e-8,
                                   atol=1e-10 * np.abs(expect).max())


def test_information_vector_gives_the_prior_free_state(fused_map, fused_ml):
    """Y^-1 y of the MAP rows is the ML estimate to first order: far closer
    to it than the MAP state is."""
    both = np.flatnonzero(fused_map.success & fused_ml.success & fused_map.observed.all(axis=1))
    assert both.size > 50
    d_free, d_map = [], []
    for i in both:
        free = np.linalg.solve(fused_map.information[i], fused_map.information_vector[i])
        for x, out in ((free, d_free), (fused_map.state[i], d_map)):
            e = x - fused_ml.state[i]
            out.append(e @ np.linalg.solve(fused_ml.covariance[i], e))
    # Measured: median Mahalanobis^2 ~1e-11 (prior-free) against ~7e-4 (MAP).
    assert np.median(d_free) < 1e-3 * np.median(d_map)
    assert np.max(d_free) < 1e-6
    # ML: Y is the inverse covariance and Y^-1 y the state itself.
    i = both[0]
    np.testing.assert_allclose(fused_ml.information[i] @ fused_ml.covariance[i], np.eye(4),
                               atol=1e-8)
    np.testing.assert_allclose(np.linalg.solve(fused_ml.information[i],
                                               fused_ml.information_vector[i]),
                               fused_ml.state[i], rtol=1e-9)


def test_measurement_information_removes_the_prior_exactly():
    prior = GaussianPrior(mean=[1.0, 2.0, 0.5, -0.5], sigmas=[2.0, 3.0, 1.5, 2.5])
    rng = np.random.default_rng(0)
    a = rng.normal(size=(3, 4, 4))
    y_true = a @ np.swapaxes(a, -1, -2) + 0.5 * np.eye(4)
    x = rng.normal(size=(3, 4))
    cov = np.linalg.inv(y_true + prior.information)
    info, vec = measurement_information(x, cov, prior.mean, prior.sigmas)
    np.testing.assert_allclose(info, y_true, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(vec, np.einsum("kij,kj->ki", np.linalg.inv(cov), x)
                               - prior.information @ prior.mean, rtol=1e-9, atol=1e-9)
    # A NaN or indefinite covariance gives NaN rows, not an error.
    bad = cov.copy()
    bad[0] = np.nan
    bad[1] = -np.eye(4)
    info, vec = measurement_information(x, bad)
    assert np.all(np.isnan(info[:2])) and np.all(np.isnan(vec[:2]))
    assert np.all(np.isfinite(info[2]))


def test_fused_file_has_time_s_and_the_information_form(recording, fused_map, tmp_path):
    path = tmp_path / "rec.h5"
    write_recording(path, recording)
    write_fused(path, fused_map)
    with h5py.File(path, "r") as f:
        g = f["fused"]
        np.testing.assert_allclose(g["time_s"][()], fused_map.frame * recording.frame_period_s)
        assert g["information"].shape == (len(fused_map), 4, 4)
        assert g["information_vector"].shape == (len(fused_map), 4)
        assert g.attrs["frame_period_s"] == recording.frame_period_s
        assert "time_origin_s" not in g.attrs
    back = read_fused(path)
    np.testing.assert_allclose(back.time_s, fused_map.frame * recording.frame_period_s)
    np.testing.assert_array_equal(back.information, fused_map.information)
    np.testing.assert_array_equal(back.information_vector, fused_map.information_vector)
    assert back.frame_period_s == recording.frame_period_s and back.time_origin_s is None


def test_time_stamps_of_a_time_stamped_recording(recording, fused_map, tmp_path):
    path = tmp_path / "stamped.h5"
    rec = dataclasses.replace(recording, frame_period_s=0.05,
                              metadata={**recording.metadata, "time_origin_s": 1.7e9 + 0.25})
    write_recording(path, rec)
    # A sequence without a clock of its own takes the file's.
    write_fused(path, dataclasses.replace(fused_map, time_s=None, frame_period_s=None,
                                          time_origin_s=None))
    back = read_fused(path)
    assert back.time_origin_s == pytest.approx(1.7e9 + 0.25)
    np.testing.assert_allclose(back.time_s, fused_map.frame * 0.05)
    # Time stamps given with the sequence win over the file's clock.
    own = dataclasses.replace(fused_map, time_s=fused_map.frame * 0.2 + 1.0)
    write_fused(path, own)
    np.testing.assert_allclose(read_fused(path).time_s, fused_map.frame * 0.2 + 1.0)


def test_a_file_of_format_1_0_still_reads(recording, fused_map, tmp_path):
    path = tmp_path / "old.h5"
    write_recording(path, recording)
    write_fused(path, fused_map)
    with h5py.File(path, "r+") as f:
        g = f["fused"]
        for name in ("time_s", "information", "information_vector"):
            del g[name]
        del g.attrs["frame_period_s"]
        g.attrs["format_version"] = "1.0"
    back = read_fused(path)
    np.testing.assert_allclose(back.time_s, fused_map.frame * recording.frame_period_s)
    np.testing.assert_allclose(back.information, fused_map.information, rtol=1e-12)
    np.testing.assert_allclose(back.information_vector, fused_map.information_vector,
                               rtol=1e-12, atol=1e-12)


# ----------------------------------------------------------------------------
# mmsnap evaluate: the NEES check
# ----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def files(recording, fused_map, tmp_path_factory):
    """The recording with its honest /fused, and a copy whose covariances
    are a quarter of the honest ones (over-confident)."""
    d = tmp_path_factory.mktemp("nees")
    good, bad = d / "good.h5", d / "bad.h5"
    write_recording(good, recording)
    write_fused(good, fused_map)
    write_recording(bad, recording)
    write_fused(bad, dataclasses.replace(fused_map, covariance=fused_map.covariance / 4.0))
    return good, bad


def test_evaluate_reports_a_failed_nees_check(files, capsys):
    good, bad = files
    assert main(["evaluate", str(bad)]) == 0           # reported, not an error
    text = capsys.readouterr().out
    assert "FAILED: NEES check failed" in text and "outside the 95% interval" in text
    assert "over-confident" in text
    assert main(["evaluate", str(bad), "--check"]) == 1
    capsys.readouterr()
    assert main(["evaluate", str(bad), "--check", "--json"]) == 1
    captured = capsys.readouterr()
    data = json.loads(captured.out)
    assert data["fused"]["nees"]["passed"] is False
    lo, hi = data["fused"]["nees"]["interval_95"]
    assert data["fused"]["nees"]["mean"] > hi
    assert f"{data['fused']['nees']['mean']:.2f}" in data["failed_checks"][0]
    assert f"({lo:.2f}, {hi:.2f})" in data["failed_checks"][0]
    assert "NEES check failed" in captured.err


def test_evaluate_check_passes_on_honest_covariances(files, capsys):
    good, _ = files
    assert main(["evaluate", str(good), "--check"]) == 0
    text = capsys.readouterr().out
    assert "NEES check passed" in text and "FAILED" not in text


def test_failed_checks_of_an_under_confident_covariance(recording, fused_map):
    m = evaluate_recording(recording, fused=dataclasses.replace(
        fused_map, covariance=fused_map.covariance * 4.0))
    assert m["fused"]["nees"]["passed"] is False
    assert m["failed_checks"] == failed_checks(m) and "under-confident" in m["failed_checks"][0]
    assert failed_checks({"fused": None}) == []


def test_fuse_recording_carries_the_recording_clock():
    """In memory too (not only through write_fused): time_s = frame x period,
    and the wall-clock origin of a time-stamped recording."""
    import dataclasses

    from mmsnap_graph import fuse_recording, simulate_recording
    rec = simulate_recording("B",
                             options=SimulationOptions(physics=None, known_poses=True, frame_period_s=0.05),
                             levels=("centroids",), n_frames=12)
    fused = fuse_recording(rec)
    np.testing.assert_allclose(fused.time_s, fused.frame * 0.05)
    assert fused.frame_period_s == 0.05 and fused.time_origin_s is None
    stamped = dataclasses.replace(rec, metadata={**rec.metadata, "time_origin_s": 1.7e9})
    assert fuse_recording(stamped).time_origin_s == 1.7e9
