"""Measurement noise from the residuals of a joint calibration
(mmsnap_graph.calibration.joint.residual_noise), against the simulator's
true centroid sigmas."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mmsnap_graph.calibration import calibrate_recording, joint_calibration, residual_noise
from mmsnap_graph.data.noise import MeasurementNoise


@pytest.mark.slow
def test_noise_is_estimated_without_metadata(recording_c_random):
    rec = dataclasses.replace(recording_c_random, metadata={})
    cal = calibrate_recording(rec)
    assert "sigmas estimated from residuals" in cal.message
    meta = recording_c_random.metadata
    truth = np.array([meta["centroid_range_std_m"], meta["centroid_omega_std_rad"],
                      meta["centroid_doppler_std_mps"]])
    dets = {n: rec.nodes[n].centroids for n in rec.node_names}
    est = MeasurementNoise(range_m=0.035, omega_rad=0.1, doppler_mps=0.18)
    for _ in range(2):  # as calibrate_recording does
        first = joint_calibration(dets, noise=est)  # no motion factors
        est = residual_noise(first, dets, noise=est)
    # range and omega: leverage-corrected, within 15% of the truth (300
    # frames x 2 nodes, ~300 residual dof per component); the Doppler of two
    # nodes without motion factors is not identifiable and keeps its value
    np.testing.assert_allclose(est.sigmas[:2], truth[:2], rtol=0.15)
    assert est.doppler_mps == 0.18
