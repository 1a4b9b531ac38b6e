"""Centroid points for calibration: the boresight bias of centroids removed."""

from __future__ import annotations

import dataclasses

import numpy as np

from factors.models import detection_to_local, measurement_model
from mmsnap_graph.calibration import LocalTracks
from mmsnap_graph.calibration.pairwise.centroid_points import debias_centroid_tracks
from mmsnap_graph.data.noise import MeasurementNoise

#: The simulator's centroid noise (sim.simulator.CENTROID_NOISE).
CENTROID_NOISE = MeasurementNoise(range_m=0.05, omega_rad=0.08, doppler_mps=0.10)


def test_debiased_centroids_lose_the_boresight_bias():
    """40000 centroids of one target at 5 m, 30 degrees off boresight, omega
    sigma 0.08: detection_to_local's boresight coordinate falls short by
    R sigma_s^2 / (2 c^3) = 2.5 mm (errors against the measured range times
    the true cosine, so that the range noise cancels: standard error of the
    mean 0.37 mm); debiased, the mean error is within 3 standard errors of
    zero, the lateral coordinate is unchanged and the estimated sigma within
    3 % of 0.08. Tracks with covariances (an EKF's) are returned unchanged."""
    rng = np.random.default_rng(3)
    n = 40000
    theta = np.radians(30)
    state = np.tile([5.0 * np.sin(theta), 5.0 * np.cos(theta), 0.0, 0.0], (n, 1))
    h, _ = measurement_model(state, np.zeros(3))
    z = h + rng.normal(size=(n, 3)) * CENTROID_NOISE.sigmas
    pts = detection_to_local(z[:, 0], z[:, 1])
    tracks = LocalTracks(frame=np.arange(n), points_m=pts, track_id=np.zeros(n, int),
                         source="centroids")
    err = pts[:, 1] - z[:, 0] * np.cos(theta)
    se = err.std() / np.sqrt(n)
    assert err.mean() < -4 * se, (err.mean(), se)
    fixed, sigma = debias_centroid_tracks(tracks)
    err = fixed.points_m[:, 1] - z[:, 0] * np.cos(theta)
    assert abs(err.mean()) < 3 * se, (err.mean(), se)
    np.testing.assert_array_equal(fixed.points_m[:, 0], pts[:, 0])
    assert abs(sigma / 0.08 - 1) < 0.03, sigma
    ekf = dataclasses.replace(tracks, source="tracks", covariances=np.tile(np.eye(2), (n, 1, 1)))
    same, sigma = debias_centroid_tracks(ekf)
    assert same is ekf and np.isnan(sigma)
