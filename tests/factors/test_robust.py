"""The robust kernels' defaults (factors.robust) and their use by the GTSAM
noise models."""

from __future__ import annotations

import gtsam
import pytest

from factors.gtsam_factors import measurement_noise
from factors.robust import ROBUST_K_DEFAULT, ROBUST_KERNELS, robust_k


def test_defaults_and_an_explicit_k():
    assert set(ROBUST_KERNELS) == set(ROBUST_K_DEFAULT) == {"huber", "cauchy"}
    assert robust_k("huber") == 1.345 and robust_k("cauchy") == 2.5
    assert robust_k("huber", 2) == 2.0 and isinstance(robust_k("huber", 2), float)


@pytest.mark.parametrize("bad", ["tukey", None, "Huber"])
def test_an_unknown_kernel_is_named(bad):
    with pytest.raises(ValueError, match=repr(bad)):
        robust_k(bad)


@pytest.mark.parametrize("robust", ROBUST_KERNELS)
def test_the_gtsam_noise_model_uses_the_default_tuning_constant(robust):
    """Without a k, the factor's mEstimator is GTSAM's kernel at the default
    constant: the same weight at a residual beyond it."""
    model = measurement_noise([0.1, 0.2, 0.3], robust)
    ref = {"huber": gtsam.noiseModel.mEstimator.Huber,
           "cauchy": gtsam.noiseModel.mEstimator.Cauchy}[robust].Create(ROBUST_K_DEFAULT[robust])
    est = model.robust()
    for e in (0.5, 3.0, 10.0):
        assert est.weight(e) == pytest.approx(ref.weight(e), rel=1e-12)
