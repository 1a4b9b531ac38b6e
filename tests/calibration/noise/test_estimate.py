"""Noise from the data: the estimators, the NoiseEstimate
type and the /noise group."""

from __future__ import annotations

import dataclasses
import re

import h5py
import numpy as np
import pytest

from mmsnap_graph.data.calibration_facts import JointNoise, NoiseNotIdentified
from mmsnap_graph.calibration import calibrate_recording
from mmsnap_graph.calibration.noise.estimate import (
    estimate_noise,
    network_noise,
    temporal_noise,
    trimmed_scale,
)
from mmsnap_graph.data.noise import MeasurementNoise, NodeNoiseEstimate, NoiseEstimate
from mmsnap_graph.data.recording import Detections
from mmsnap_graph.errors import FileFormatError, ValidationError
from mmsnap_graph.io import write_recording
from mmsnap_graph.io.noise import NOISE_LAYOUT, read_noise, write_noise
from mmsnap_graph.sim import simulate_recording
from mmsnap_graph.sim import SimulationOptions

from _shared import ROOT

TRUE = MeasurementNoise(range_m=0.05, omega_rad=0.08, doppler_mps=0.10)
THREE = {"S1": [0.0, 0.0, 0.0], "S2": [0.0, 7.0, np.pi], "S3": [3.5, 3.5, np.pi / 2]}


@pytest.fixture(scope="module")
def rec3():
    return simulate_recording(THREE, "straight",
                              SimulationOptions(physics=None, centroid_noise=TRUE, known_poses=True),
                              levels=("centroids",), n_frames=400, seed=11)


@pytest.fixture(scope="module")
def rec2():
    return simulate_recording("C", "straight",
                              SimulationOptions(physics=None, centroid_noise=TRUE, known_poses=True),
                              levels=("centroids",), n_frames=400, seed=12)


def test_trimmed_scale_is_consistent_and_ignores_ghosts():
    rng = np.random.default_rng(0)
    e = 0.3 * rng.standard_normal(20000)
    s, kept = trimmed_scale(e)
    assert s == pytest.approx(0.3, rel=0.02)
    assert kept > 0.99 * e.size
    e[:2000] = rng.uniform(-30, 30, 2000)   # 10 % ghosts
    assert trimmed_scale(e)[0] == pytest.approx(0.3, rel=0.04)
    assert np.isnan(trimmed_scale(np.array([]))[0])


def test_temporal_noise_sees_white_noise_through_a_smooth_trend():
    rng = np.random.default_rng(1)
    t = np.arange(3000) * 0.15
    trend = np.stack([5 + 1.5 * np.sin(2 * np.pi * t / 20), 2.5 * np.sin(2 * np.pi * t / 30),
                      0.8 * np.cos(2 * np.pi * t / 15)], -1)
    z = trend + rng.standard_normal((t.size, 3)) * [0.02, 0.05, 0.2]
    det = Detections(frame=np.arange(t.size), range_m=z[:, 0], omega_rad=z[:, 1],
                     doppler_mps=z[:, 2])
    sig, counts = temporal_noise(det)
    np.testing.assert_allclose(sig, [0.02, 0.05, 0.2], rtol=0.06)
    assert np.all(counts > 2900)
    # a sequence shorter than 5 frames identifies nothing
    sig, counts = temporal_noise(det.select(np.arange(4)))
    assert np.all(np.isnan(sig)) and np.all(counts == 0)


def test_per_node_estimate_of_three_nodes_is_close_to_the_truth(rec3):
    est = estimate_noise(rec3)
    assert est.method == "network+temporal"
    assert list(est.nodes) == ["S1", "S2", "S3"]
    for name, e in est.nodes.items():
        assert e.identified == (True, True, True), name
        # per node ~2-5 % standard error (module doc): 15 % is > 3 standard errors
        np.testing.assert_allclose(e.noise.sigmas, TRUE.sigmas, rtol=0.15, err_msg=name)
        assert min(e.n_residuals) > 300
    # the paper's sigmas would be far off: the test can fail
    assert not np.allclose(MeasurementNoise().sigmas, TRUE.sigmas, rtol=0.15)


def test_different_nodes_keep_their_own_sigmas():
    a = simulate_recording("C", "straight",
                           SimulationOptions(physics=None, centroid_noise=TRUE, known_poses=True),
                           levels=("centroids",), n_frames=500, seed=5)
    loud = MeasurementNoise(range_m=0.10, omega_rad=0.16, doppler_mps=0.2)
    b = simulate_recording("C", "straight",
                           SimulationOptions(physics=None, centroid_noise=loud, known_poses=True),
                           levels=("centroids",), n_frames=500, seed=5)
    rec = a.with_node(b.nodes["S2"])  # same truth, S2 twice as noisy
    est = estimate_noise(rec)
    np.testing.assert_allclose(est.nodes["S1"].noise.sigmas, TRUE.sigmas, rtol=0.2)
    np.testing.assert_allclose(est.nodes["S2"].noise.sigmas, loud.sigmas, rtol=0.2)


def test_two_nodes_cross_node_residuals_cannot_identify_the_doppler():
    # network A: two nodes looking the same way; the two Dopplers fix each
    # frame's velocity, and the two ranges are checked only together
    rec = simulate_recording("A", "straight",
                             SimulationOptions(physics=None, centroid_noise=TRUE, known_poses=True),
                             levels=("centroids",), n_frames=400, seed=12)
    est = estimate_noise(rec, method="network")
    for e in est.nodes.values():
        assert not e.identified[2]
        assert e.noise.doppler_mps == MeasurementNoise().doppler_mps   # the fallback, said so
        assert "fix each frame's velocity" in e.reasons[2]
        assert e.n_residuals[2] == 0
    assert "NOT identified" in est.summary()
    # with the nodes' own sequences everything is identified
    both = estimate_noise(rec)
    for e in both.nodes.values():
        assert e.identified == (True, True, True)
        np.testing.assert_allclose(e.noise.sigmas, TRUE.sigmas, rtol=0.15)


def test_network_noise_without_motion_assumption_and_with_ghosts(rec3):
    dets = {n: rec3.nodes[n].centroids for n in rec3.node_names}
    sig, dof, counts = network_noise(dets, rec3.truth.node_poses, initial=MeasurementNoise())
    # range and spatial frequency: identified per node from the cross-node
    # residuals alone (the Doppler of three nodes only weakly: one check per frame)
    np.testing.assert_allclose(sig[:, :2], np.tile(TRUE.sigmas[:2], (3, 1)), rtol=0.25)
    assert np.all(dof[:, :2] > 25)
    assert np.all(counts > 390)
    rng = np.random.default_rng(3)
    d = dets["S2"]
    bad = rng.random(len(d)) < 0.1
    ghost = dataclasses.replace(d, range_m=np.where(bad, rng.uniform(1, 8, len(d)), d.range_m))
    sig2, _, _ = network_noise({**dets, "S2": ghost}, rec3.truth.node_poses,
                               initial=MeasurementNoise())
    np.testing.assert_allclose(sig2[:, :2], np.tile(TRUE.sigmas[:2], (3, 1)), rtol=0.3)
    with pytest.raises(ValidationError, match="at least two nodes"):
        network_noise({"S1": dets["S1"]}, rec3.truth.node_poses)
    with pytest.raises(ValidationError, match="no pose"):
        network_noise(dets, {"S1": np.zeros(3)})


def test_no_poses_gives_the_temporal_estimate_and_says_so(rec2):
    rec = rec2
    for n in rec.node_names:
        rec = rec.with_node(dataclasses.replace(rec.nodes[n], pose=None))
    est = estimate_noise(rec)
    assert "no node poses" in est.message
    for e in est.nodes.values():
        assert "network" not in e.method
        assert all(e.identified)


def test_too_little_data_is_reported_not_identified(rec2):
    rec = rec2
    for n in rec.node_names:
        node = rec.nodes[n]
        rec = rec.with_node(dataclasses.replace(node, centroids=node.centroids.select(
            np.arange(6))))
    fb = MeasurementNoise(range_m=0.3, omega_rad=0.3, doppler_mps=0.3)
    est = estimate_noise(rec, fallback=fb)
    assert not est.any_identified
    for e in est.nodes.values():
        assert e.identified == (False, False, False)
        np.testing.assert_allclose(e.noise.sigmas, fb.sigmas)
        assert all("dof" in r for r in e.reasons)
    with pytest.raises(ValidationError, match="method"):
        estimate_noise(rec, method="magic")
    with pytest.raises(ValidationError, match="min_dof"):
        estimate_noise(rec, min_dof=0)


def test_noise_estimate_type_validates_and_pools():
    n1 = NodeNoiseEstimate(noise=TRUE, identified=(1, 1, 0), n_residuals=(10, 10, 0),
                           method="temporal", reasons=("", "", "short"))
    assert n1.identified == (True, True, False)
    with pytest.raises(ValidationError, match="identified"):
        NodeNoiseEstimate(noise=TRUE, identified=(True,), n_residuals=(1, 1, 1), method="x")
    with pytest.raises(ValidationError, match="n_residuals"):
        NodeNoiseEstimate(noise=TRUE, identified=(1, 1, 1), n_residuals=(1, -1, 1), method="x")
    with pytest.raises(ValidationError, match="MeasurementNoise"):
        NodeNoiseEstimate(noise=(1, 2, 3), identified=(1, 1, 1), n_residuals=(1, 1, 1),
                          method="x")
    with pytest.raises(ValidationError, match="at least one node"):
        NoiseEstimate(nodes={})
    loud = MeasurementNoise(range_m=0.1, omega_rad=0.08, doppler_mps=0.1)
    n2 = NodeNoiseEstimate(noise=loud, identified=(1, 1, 0), n_residuals=(30, 10, 0),
                           method="temporal", reasons=("", "", "short"))
    est = NoiseEstimate(nodes={"A": n1, "B": n2})
    pooled = est.pooled()
    assert pooled.range_m == pytest.approx(np.sqrt((10 * 0.05**2 + 30 * 0.1**2) / 40))
    assert pooled.omega_rad == pytest.approx(0.08)
    assert est.per_node == {"A": TRUE, "B": loud}
    assert "doppler 0.1 m/s NOT identified, fallback used (short)" in est.summary()


def test_noise_group_round_trip_absent_and_damaged(tmp_path, rec2):
    path = tmp_path / "r.h5"
    write_recording(path, rec2)
    assert read_noise(path) is None
    est = estimate_noise(rec2, method="network")
    out = write_noise(path, est)
    assert out == path
    back = read_noise(path)
    assert back == est
    copy = write_noise(path, est, output=tmp_path / "copy.h5")
    assert read_noise(copy) == est
    with h5py.File(path, "r+") as f:
        del f["noise/identified"]
    with pytest.raises(FileFormatError, match="identified is missing"):
        read_noise(path)
    write_noise(path, est)
    with h5py.File(path, "r+") as f:
        f["noise/sigmas"][0, 0] = -1.0
    with pytest.raises(FileFormatError, match="inconsistent.*range_m"):
        read_noise(path)
    write_noise(path, est)
    with h5py.File(path, "r+") as f:
        del f["noise/sigmas"]
        f["noise"].create_dataset("sigmas", data=np.ones((1, 3)))
    with pytest.raises(FileFormatError, match="sigmas must have shape"):
        read_noise(path)
    with pytest.raises(FileFormatError, match="does not exist"):
        read_noise(tmp_path / "none.h5")
    (tmp_path / "junk.h5").write_bytes(b"not hdf5")
    with pytest.raises(FileFormatError):
        read_noise(tmp_path / "junk.h5")
    with pytest.raises(FileFormatError):
        write_noise(tmp_path / "junk.h5", est)
    assert (tmp_path / "junk.h5").read_bytes() == b"not hdf5"   # left as it was


def test_format_doc_quotes_the_noise_layout():
    from pathlib import Path

    doc = (ROOT / "docs" / "FORMAT.md").read_text()
    assert NOISE_LAYOUT in doc


def test_calibration_uses_the_data_not_the_metadata(rec2):
    wrong = dict(rec2.metadata, centroid_range_std_m=1.0, centroid_omega_std_rad=1.0,
                 centroid_doppler_std_mps=1.0)
    cal = calibrate_recording(dataclasses.replace(rec2, metadata=wrong, nodes={
        n: dataclasses.replace(v, pose=None) for n, v in rec2.nodes.items()}))
    assert cal.method == "joint" and cal.noise is not None
    for e in cal.noise.nodes.values():
        assert all(e.identified)
        np.testing.assert_allclose(e.noise.sigmas, TRUE.sigmas, rtol=0.15)
    said = cal.fact(JointNoise)  # the joint graph's noise came from the data too
    assert said.source == "temporal" and all(said.identified)
    assert cal.fact(NoiseNotIdentified) is None


def test_noise_for_fusion_per_node_pooled_or_the_papers(tmp_path, rec2):
    from mmsnap_graph.io.noise import noise_for_fusion

    path = tmp_path / "r.h5"
    write_recording(path, rec2)
    noise, text = noise_for_fusion(path, rec2.node_names)
    assert noise == MeasurementNoise() and "paper's sigmas" in text
    est = estimate_noise(rec2)
    write_noise(path, est)
    noise, text = noise_for_fusion(path, rec2.node_names)
    assert noise == est.per_node and re.search(r"^  S2  range [0-9.]+ m", text, re.M)
    pooled, text = noise_for_fusion(path, rec2.node_names, per_node=False)
    assert pooled == est.pooled() and "one noise for every node" in text
    with pytest.raises(FileFormatError, match=r"no sigmas for nodes \['S9'\]"):
        noise_for_fusion(path, ["S1", "S9"])


def test_a_node_without_centroids_is_reported_not_identified(rec2):
    rec = rec2.with_node(dataclasses.replace(rec2.nodes["S2"], centroids=None))
    est = estimate_noise(rec)
    assert est.nodes["S2"].identified == (False, False, False)
    assert est.nodes["S2"].reasons == ("no centroids",) * 3
    assert est.nodes["S2"].noise == MeasurementNoise()
    assert all(est.nodes["S1"].identified)                   # its own sequence
    assert est.nodes["S1"].method == "temporal"


@pytest.mark.parametrize("fraction", [0.1, 0.2])
def test_ghost_centroids_do_not_inflate_the_estimate(rec3, fraction):
    rng = np.random.default_rng(7)
    rec, n_bad = rec3, 0
    for n in rec.node_names:
        d = rec.nodes[n].centroids
        bad = rng.random(len(d)) < fraction
        n_bad += int(bad.sum())
        ghost = dataclasses.replace(
            d, range_m=np.where(bad, rng.uniform(1, 8, len(d)), d.range_m),
            omega_rad=np.where(bad, rng.uniform(-2.5, 2.5, len(d)), d.omega_rad),
            doppler_mps=np.where(bad, rng.uniform(-2, 2, len(d)), d.doppler_mps))
        rec = rec.with_node(dataclasses.replace(rec.nodes[n], centroids=ghost))
    assert n_bad > 100
    est = estimate_noise(rec)
    for name, e in est.nodes.items():
        assert all(e.identified), name
        np.testing.assert_allclose(e.noise.sigmas, TRUE.sigmas, rtol=0.15, err_msg=name)
    # without the ghost screening the differences see the ghosts: the test can fail
    d = rec.nodes["S1"].centroids
    raw, _ = temporal_noise(d, remove_ghosts=False)
    assert raw[0] > 1.15 * TRUE.range_m


def test_doppler_of_real_point_clouds_is_estimated_not_the_fallback():
    """On the real model's clustered point clouds a body's micro-Doppler
    makes its centroid Doppler rough (errors against the true torso: std 0.37
    and 0.40 m/s on S1 and S2 here, lag-1 correlation ~0), so few rows pass
    the motion estimator's gate (10-13 dof); the temporal estimate (~80 dof
    per node) must stand rather than the paper's 0.1807 m/s, which made the
    fused velocity NEES 6 instead of 2."""
    from mmsnap_graph.app.pipeline import process_recording

    rec = simulate_recording("B", "random", SimulationOptions(), n_frames=600, seed=0)
    rec, _ = process_recording(rec)
    est = estimate_noise(rec, poses=rec.truth.node_poses)
    for name, node in est.nodes.items():
        assert node.identified[2], (name, node.reasons[2])
        assert 0.2 <= node.noise.doppler_mps <= 0.45, (name, node.noise.doppler_mps)


def _rounded_ranges(rec, step_m=1.0):
    """``rec`` with every node's centroid ranges rounded to ``step_m`` (a
    coarse logger)."""
    for name in rec.node_names:
        c = rec.nodes[name].centroids
        rounded = dataclasses.replace(c, range_m=np.round(c.range_m / step_m) * step_m)
        rec = rec.with_node(dataclasses.replace(rec.nodes[name], centroids=rounded))
    return rec


def test_ranges_rounded_to_whole_metres_are_not_identified_and_do_not_crash(rec2):
    """Before: the differences of repeated ranges gave a temporal sigma of
    ~1e-16 m, whose weight made the frames' solve singular: LinAlgError out
    of estimate_noise (`mmsnap noise`, `mmsnap calibrate`)."""
    rec = _rounded_ranges(rec2)
    sig, counts = temporal_noise(rec.nodes["S1"].centroids)
    assert np.isnan(sig[0]) and counts[0] == 0
    assert np.all(np.isfinite(sig[1:])) and np.all(counts[1:] > 100)  # omega, Doppler kept
    poses = {n: rec.nodes[n].pose for n in rec.node_names}
    est = estimate_noise(rec, poses=poses)
    for node in est.nodes.values():
        assert node.noise.range_m >= 0.035 - 1e-12  # the rounding's 0.29 m or the fallback
    # ranges on a fine grid (1 mm: most differences not zero) keep their estimate
    fine = temporal_noise(_rounded_ranges(rec2, 1e-3).nodes["S1"].centroids)[0]
    np.testing.assert_allclose(fine[0], TRUE.range_m, rtol=0.15)
