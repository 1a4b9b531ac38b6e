"""The joint calibration graph (mmsnap_graph.calibration.joint.graph): the
constant-velocity factors it builds between frames, and the dense Schur
complement it falls back to when the marginals fail."""

from __future__ import annotations

import numpy as np

from mmsnap_graph.calibration import joint_calibration
from mmsnap_graph.calibration.joint.graph import motion_spec
from mmsnap_graph.data.calibration_facts import PoseCovariance
from mmsnap_graph.data.noise import MeasurementNoise
from mmsnap_graph.data.recording import Detections
from mmsnap_graph.sim.scenes import COMMON_AREA_CENTERS, PAPER_CONFIGURATIONS, synthetic_scene

STANDING_NOISE = MeasurementNoise(range_m=0.01, omega_rad=0.02, doppler_mps=0.05)


def _detections(scene):
    return {n: Detections(frame=scene.frame, range_m=z[:, 0], omega_rad=z[:, 1],
                          doppler_mps=z[:, 2]) for n, z in scene.measurements.items()}


def _scene(config, rng, **kw):
    return synthetic_scene(PAPER_CONFIGURATIONS[config], center_m=COMMON_AREA_CENTERS[config],
                           rng=rng, **kw)


def test_motion_factors_join_frames_no_more_than_the_gap_apart():
    """Frames 0 1 2 5 6 20 with a 3-frame limit at 0.15 s: factors between the
    pairs (0,1) (1,2) (2,5) (5,6), 0.15 0.15 0.45 0.15 s apart; none across
    the 14-frame hole; none without motion."""
    frames = np.array([0, 1, 2, 5, 6, 20])
    spec = motion_spec(frames, True, 0.15, 3, 2.0, robust="huber", k=1.5)
    np.testing.assert_array_equal(spec.index, [0, 1, 2, 3])
    np.testing.assert_allclose(spec.dt_s, [0.15, 0.15, 0.45, 0.15], rtol=1e-15)
    assert spec.as_tuple()[2:] == (2.0, "huber", 1.5)
    sub = spec.subset(np.array([True, False, True, False]), None)
    np.testing.assert_array_equal(sub.index, [0, 2])
    assert sub.robust is None and sub.k == 1.5
    assert motion_spec(frames, False, 0.15, 3, 2.0) is None


def test_singular_marginals_fall_back_to_the_schur_complement(monkeypatch):
    """Force the elimination for the marginals to fail (as on an exactly singular system): the
    dense Schur complement names the unobservable direction and puts inf in
    the covariance."""
    import mmsnap_graph.calibration.joint.graph as joint_graph_mod

    def broken(*args, **kwargs):
        raise RuntimeError("Indeterminant linear system detected")

    monkeypatch.setattr(joint_graph_mod, "eliminate_in_order", broken)
    rng = np.random.default_rng(9)
    scene = _scene("C", rng, n_frames=60, noise=STANDING_NOISE, kind="standing")
    res = joint_calibration(_detections(scene), noise=STANDING_NOISE,
                            initial_poses={"S2": scene.poses["S2"]})
    assert not res.success
    covariance = next(f for f in res.facts if isinstance(f, PoseCovariance))
    assert covariance.method == "schur" and "(Indeterminant" in covariance.failure
    d = res.unobservable["S2"][0]
    assert abs(d[0]) > 0.9
    cov = res.covariances["S2"]
    assert np.isinf(cov[0, 0]) and np.isinf(cov[2, 2])
