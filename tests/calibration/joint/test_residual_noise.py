"""Measurement noise from the residuals of a joint calibration
(mmsnap_graph.calibration.joint.residual_noise), against the simulator's
true centroid sigmas."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mmsnap_graph.calibration import calibrate_recording, joint_calibration, residual_noise
from mmsnap_graph.data.calibration_facts import JointNoise
from mmsnap_graph.data.noise import MeasurementNoise
from mmsnap_graph.data.recording import Detections
from mmsnap_graph.errors import CalibrationError
from mmsnap_graph.sim.scenes import synthetic_scene

from _shared import NETWORK_3


@pytest.mark.slow
def test_noise_is_estimated_without_metadata(recording_c_random):
    rec = dataclasses.replace(recording_c_random, metadata={})
    cal = calibrate_recording(rec)
    assert cal.fact(JointNoise).source == "temporal"
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


#: Sigmas of the synthetic scene below: not the starting guess's.
TRUE_NOISE = MeasurementNoise(range_m=0.04, omega_rad=0.06, doppler_mps=0.12)


def _scene_detections(seed):
    scene = synthetic_scene(NETWORK_3, center_m=np.array([1.5, 4.0]), n_frames=200,
                            noise=TRUE_NOISE, rng=np.random.default_rng(seed))
    return scene, {n: Detections(frame=scene.frame, range_m=z[:, 0], omega_rad=z[:, 1],
                                 doppler_mps=z[:, 2]) for n, z in scene.measurements.items()}


def test_three_nodes_identify_every_sigma():
    """Three nodes see each frame (200 frames, white noise of known sigmas):
    solve without motion factors and re-estimate, three times from a guess
    2-2.5x off (as calibrate_recording iterates). Over seeds 0-7 the mean
    ratio of estimate to truth is within 10% of 1 for each component
    (measured: range 0.95, omega 1.01, Doppler 0.98; per seed 0.87-1.05)."""
    ratios = []
    for seed in range(8):
        scene, dets = _scene_detections(seed)
        est = MeasurementNoise(range_m=0.1, omega_rad=0.15, doppler_mps=0.3)
        for _ in range(3):
            res = joint_calibration(dets, noise=est,
                                    initial_poses={n: scene.poses[n] for n in ("S2", "S3")})
            assert res.success, res.facts
            est = residual_noise(res, dets, noise=est)
        ratios.append(est.sigmas / TRUE_NOISE.sigmas)
    np.testing.assert_allclose(np.mean(ratios, axis=0), 1.0, atol=0.1)


def test_no_inlier_detection_is_a_calibration_error():
    scene, dets = _scene_detections(0)
    res = joint_calibration(dets, noise=TRUE_NOISE,
                            initial_poses={n: scene.poses[n] for n in ("S2", "S3")})
    other = {"S9": dets["S1"]}  # a node the solution does not hold
    with pytest.raises(CalibrationError, match="no inlier detection"):
        residual_noise(res, other, noise=TRUE_NOISE)
