"""Statistics of the decalibration monitor (mmsnap_graph.calibration.monitor.stats):
per-frame pose contributions and the Gauss-Newton re-calibration of one pose."""

from __future__ import annotations

import numpy as np

from factors.models import measurement_model
from mmsnap_graph.calibration.monitor.stats import (compose_pose, frame_contributions,
                                                    recalibrate_pose)
from mmsnap_graph.data.noise import MeasurementNoise

#: The simulator's centroid noise (sim.simulator.CENTROID_NOISE).
NOISE = MeasurementNoise(range_m=0.05, omega_rad=0.08, doppler_mps=0.10)


def test_contributions_and_gauss_newton_recover_a_noise_free_pose_error():
    rng = np.random.default_rng(0)
    states = np.column_stack([rng.uniform(-1.5, 1.5, 60), rng.uniform(2.5, 4.5, 60),
                              rng.normal(0, 1, 60), rng.normal(0, 1, 60)])
    covs = np.tile(np.diag([1e-4, 1e-4, 1e-2, 1e-2]), (60, 1, 1))
    assumed = np.array([0.0, 7.0, np.pi])
    for delta in (np.array([1e-4, -2e-4, 3e-5]), np.array([0.1, 0.0, 0.0]),
                  np.array([0.0, 0.0, np.deg2rad(2.0)])):
        true_pose = compose_pose(assumed, delta)
        z, _ = measurement_model(states, true_pose)
        fc = frame_contributions(assumed, states, covs, z, NOISE, huber_k=None)
        est = np.linalg.solve(fc.a.sum(0), fc.b.sum(0))
        if np.max(np.abs(delta)) < 1e-3:                 # first order: the linear estimate
            np.testing.assert_allclose(est, delta, rtol=0.02, atol=1e-7)
        fit = recalibrate_pose(assumed, states, covs, z, NOISE)
        assert fit.success
        np.testing.assert_allclose(fit.pose, true_pose, atol=1e-7)
        assert np.all(np.linalg.eigvalsh(fit.covariance) > 0)
    # a standing target cannot fix the pose: success=False, no exception
    still = np.tile(states[:1], (20, 1))
    z, _ = measurement_model(still, assumed)
    assert not recalibrate_pose(assumed, still, covs[:20], z, NOISE).success
