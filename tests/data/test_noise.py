"""Noise and prior records (mmsnap_graph.data.noise): validation naming the
field, the prior's information, and the pooled noise of an estimate against a
hand computation."""

from __future__ import annotations

import numpy as np
import pytest

from mmsnap_graph.data.noise import (NOISE_METADATA_KEYS, GaussianPrior, MeasurementNoise,
                                     NodeNoiseEstimate, declared_noise,
                                     NoiseEstimate)
from mmsnap_graph.errors import ValidationError


def test_measurement_noise_sigmas_and_the_paper_default():
    n = MeasurementNoise(range_m=0.1, omega_rad=0.2, doppler_mps=0.3)
    np.testing.assert_array_equal(n.sigmas, [0.1, 0.2, 0.3])
    assert MeasurementNoise().sigmas.shape == (3,) and np.all(MeasurementNoise().sigmas > 0)


@pytest.mark.parametrize("field, value", [("range_m", 0.0), ("omega_rad", -0.1),
                                          ("doppler_mps", float("nan")),
                                          ("range_m", float("inf")), ("omega_rad", "wide")])
def test_bad_sigmas_are_named(field, value):
    with pytest.raises(ValidationError, match=f"noise {field}"):
        MeasurementNoise(**{field: value})


def test_prior_information_is_the_inverse_covariance():
    prior = GaussianPrior(mean=[1.0, 2.0, 0.0, 0.0], sigmas=[2.0, 3.0, 0.5, 4.0])
    np.testing.assert_allclose(prior.information,
                               np.linalg.inv(np.diag(prior.sigmas**2)), rtol=1e-15)
    with pytest.raises(ValidationError, match="prior sigmas must be > 0"):
        GaussianPrior(sigmas=[1.0, 1.0, 0.0, 1.0])
    with pytest.raises(ValidationError, match="prior mean"):
        GaussianPrior(mean=[1.0, 2.0])
    with pytest.raises(ValueError):  # read-only, so that a shared default cannot change
        prior.mean[0] = 5.0


def _node(sigmas, identified, counts, reasons=("", "", "")):
    return NodeNoiseEstimate(noise=MeasurementNoise(range_m=sigmas[0], omega_rad=sigmas[1],
                                                    doppler_mps=sigmas[2]),
                             identified=identified, n_residuals=counts, method="test",
                             reasons=reasons)


def test_pooled_noise_is_the_count_weighted_rms():
    """Range: 100 residuals at 0.1 and 300 at 0.2 give sqrt((100 0.01 + 300
    0.04) / 400); omega: no node identified it, equal weights; doppler: one
    node's count only."""
    est = NoiseEstimate(nodes={
        "S1": _node((0.1, 0.3, 0.5), (True, False, True), (100, 0, 50),
                    ("", "too few residuals", "")),
        "S2": _node((0.2, 0.1, 0.9), (True, False, False), (300, 0, 0),
                    ("", "too few residuals", "no motion")),
    })
    pooled = est.pooled()
    np.testing.assert_allclose(pooled.sigmas, [np.sqrt((100 * 0.01 + 300 * 0.04) / 400),
                                               np.sqrt((0.09 + 0.01) / 2), 0.5], rtol=1e-12)
    assert est.any_identified
    assert est.per_node["S2"].range_m == 0.2
    lines = est.summary().splitlines()
    assert len(lines) == 2 and lines[0].startswith("S1 [test]: range 0.1 m estimated (100 ")
    assert "doppler 0.9 m/s NOT identified, fallback used (no motion)" in lines[1]


def test_estimate_records_are_checked():
    with pytest.raises(ValidationError, match="at least one node"):
        NoiseEstimate(nodes={})
    with pytest.raises(ValidationError, match=r"nodes\['S1'\] must be a NodeNoiseEstimate"):
        NoiseEstimate(nodes={"S1": MeasurementNoise()})
    with pytest.raises(ValidationError, match="n_residuals must be 3 integers >= 0"):
        _node((0.1, 0.1, 0.1), (True, True, True), (1, -1, 1))
    with pytest.raises(ValidationError, match="identified must hold 3 values"):
        _node((0.1, 0.1, 0.1), (True, True), (1, 1, 1))
    with pytest.raises(ValidationError, match="noise must be a MeasurementNoise"):
        NodeNoiseEstimate(noise=(0.1, 0.1, 0.1), identified=(True,) * 3, n_residuals=(1, 1, 1),
                          method="x")


def test_declared_noise_reads_the_simulators_keys():
    from mmsnap_graph.sim import simulate_recording

    rec = simulate_recording("C", "straight", levels=("centroids",), n_frames=5, seed=0)
    noise = declared_noise(rec.metadata)
    assert noise is not None
    assert noise.sigmas == pytest.approx([rec.metadata[k] for k in NOISE_METADATA_KEYS])
    assert declared_noise({}) is None


@pytest.mark.parametrize("value", [None, "x", float("nan"), 0.0, -1.0, float("inf")])
def test_declared_noise_is_none_when_a_value_is_no_sigma(value):
    metadata = dict(zip(NOISE_METADATA_KEYS, (0.05, 0.1, 0.2)))
    assert declared_noise(metadata) == MeasurementNoise(range_m=0.05, omega_rad=0.1,
                                                       doppler_mps=0.2)
    metadata[NOISE_METADATA_KEYS[1]] = value
    assert declared_noise(metadata) is None
