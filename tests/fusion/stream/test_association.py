"""The stream's fast path (issue 13, latency): the float association equals
associate_frame's decisions, the numpy solver's stream equals the GTSAM
stream, and the central tracker's float algebra equals the numpy
information-form filter it replaced."""

from __future__ import annotations

import numpy as np
import pytest

from factors.models import predict_measurements, wrap_angle
from factors.motion import cv_process_noise, cv_transition
from mmsnap_graph import MeasurementNoise
from mmsnap_graph.data.noise import GaussianPrior
from mmsnap_graph.data.results import Status
from mmsnap_graph.fusion.association import associate_frame
from mmsnap_graph.fusion.solvers.scalar import COVARIANCE_TOLERANCE, STATE_TOLERANCE
from mmsnap_graph.fusion.stream.frame_stream import FrameStream, recording_frames
from mmsnap_graph.fusion.stream.association import StreamAssociator
from mmsnap_graph.sim import simulate_recording
from mmsnap_graph.tracking.central import (CentralConfig, CentralTracker, measurement_information,
                                           spd_inverse_4x4)
from mmsnap_graph.sim import SimulationOptions
from _fusion import stream_config

SQUARE = np.array([[0.0, 0.0, 0.0], [0.0, 7.0, np.pi], [-3.5, 3.5, -np.pi / 2], [3.5, 3.5, np.pi / 2]])
NETWORK = {"S1": SQUARE[0], "S2": SQUARE[1], "S3": SQUARE[2], "S4": SQUARE[3]}
NOISES = (MeasurementNoise(), MeasurementNoise(range_m=0.05, omega_rad=0.5, doppler_mps=0.15),
          MeasurementNoise(range_m=0.03, omega_rad=0.9, doppler_mps=0.2), MeasurementNoise())


def _detections(rng, n_targets, p_miss, one_per_node):
    """One frame of the square network: each node sees each target with
    probability 1 - p_miss (one of them at most with ``one_per_node``)."""
    states = np.column_stack([rng.uniform(-3.0, 3.0, n_targets), rng.uniform(0.5, 6.5, n_targets),
                              rng.normal(0.0, 0.7, (n_targets, 2))])
    out = []
    for pose in SQUARE:
        z = predict_measurements(states, pose) + rng.normal(size=(n_targets, 3)) * [0.1, 0.2, 0.1]
        z[:, 1] = np.clip(wrap_angle(z[:, 1]), -np.pi, np.pi)
        z = z[rng.random(n_targets) >= p_miss]
        out.append(z[:1] if one_per_node else z)
    return out


@pytest.mark.parametrize("noise", [MeasurementNoise(), NOISES], ids=["one noise", "per-node noise"])
def test_fast_association_makes_the_decisions_of_associate_frame(noise):
    rng = np.random.default_rng(21)
    noises = noise if isinstance(noise, tuple) else (noise,) * 4
    assoc = StreamAssociator(SQUARE, noises, 0.999)
    n_groups = []
    for k in range(600):
        # One target, two targets with one detection per node (several groups),
        # two to four targets (several detections per node; five or more go to
        # associate_frame itself).
        n_targets = (1, 2, 2, 3, 4, 5)[k % 6]
        dets = _detections(rng, n_targets, 0.25, one_per_node=k % 6 < 2)
        ref = associate_frame(dets, SQUARE, noise, gate_probability=0.999).members
        got = assoc.members(dets)
        np.testing.assert_array_equal(got, ref)
        assert got.dtype == np.int64
        n_groups.append(len(ref))
    assert max(n_groups) >= 3 and min(n_groups) <= 1  # groups split and joined


def test_fast_association_hands_degenerate_detections_to_associate_frame():
    assoc = StreamAssociator(SQUARE, (MeasurementNoise(),) * 4, 0.999)
    dets = [np.array([[0.0, 0.0, 0.0]]), np.array([[3.5, 0.0, 0.1]]), np.zeros((0, 3)),
            np.array([[1e-300, np.pi, 0.0]])]
    ref = associate_frame(dets, SQUARE, MeasurementNoise()).members
    np.testing.assert_array_equal(assoc.members(dets), ref)
    assert assoc.members([np.zeros((0, 3))] * 4).shape == (0, 4)


@pytest.fixture(scope="module")
def recording():
    """Four nodes, two walking targets, 10 % missed centroids."""
    return simulate_recording(NETWORK, "random",
                              SimulationOptions(physics=None, n_targets=2, known_poses=True, centroid_p_miss=0.1),
                              levels=("centroids",), n_frames=120, seed=5)


@pytest.mark.parametrize("prior", [GaussianPrior(), None], ids=["MAP", "ML"])
def test_numpy_stream_equals_the_gtsam_stream(recording, prior):
    streams = [FrameStream(recording.node_names, SQUARE, config=stream_config(solver=s, prior=prior))
               for s in ("scalar", "gtsam")]
    n_ok = 0
    for _, t, d in recording_frames(recording):
        a, b = (s.push(t, d) for s in streams)
        assert a.ok and b.ok
        np.testing.assert_array_equal(a.members, b.members)
        np.testing.assert_array_equal(a.status, b.status)
        ok = b.status == Status.OK
        n_ok += int(ok.sum())
        sig = np.sqrt(np.einsum("gii->gi", b.covariance[ok]))
        assert np.all(np.abs(a.state[ok] - b.state[ok]) <= STATE_TOLERANCE * sig)
        assert np.all(np.abs(a.covariance[ok] - b.covariance[ok])
                      <= COVARIANCE_TOLERANCE * np.einsum("gi,gj->gij", sig, sig))
        np.testing.assert_array_equal(a.track_id, b.track_id)
        np.testing.assert_allclose(a.track_state, b.track_state, rtol=0, atol=1e-6)
    assert n_ok > 150


def test_spd_inverse_4x4_equals_numpy_and_refuses_indefinite_matrices():
    rng = np.random.default_rng(3)
    for _ in range(50):
        a = rng.normal(size=(4, 4)) * rng.uniform(0.01, 10.0, 4)
        p = a @ a.T + 1e-3 * np.eye(4)
        inv = spd_inverse_4x4(p)
        np.testing.assert_array_equal(inv, inv.T)
        np.testing.assert_allclose(inv @ p, np.eye(4), atol=1e-8 * np.linalg.cond(p))
    with pytest.raises(np.linalg.LinAlgError):
        spd_inverse_4x4(np.diag([1.0, 1.0, -1.0, 1.0]))
    with pytest.raises(np.linalg.LinAlgError):
        spd_inverse_4x4(np.full((4, 4), np.nan))


def _reference_information(x, p, mean, sigmas):
    """measurement_information as it was written with numpy (before the float path)."""
    info = np.linalg.inv(0.5 * (p + p.T))
    eta = info @ x
    lam = 1.0 / sigmas**2
    info, eta = info - np.diag(lam), eta - lam * mean
    w, v = np.linalg.eigh(0.5 * (info + info.T))
    return (v * np.maximum(w, 0.0)) @ v.T, eta


class _ReferenceTracker:
    """One target, the information-form Kalman filter of CentralTracker in numpy."""

    def __init__(self, cfg, prior):
        self.cfg, self.prior, self.x, self.p = cfg, prior, None, None

    def step(self, z, r, t):
        if self.x is None:
            self.x, self.p = z.copy(), 0.5 * (r + r.T)
            for k in (2, 3):
                self.p[k, k] = max(self.p[k, k], self.cfg.init_velocity_sigma_mps**2)
            return
        f, q = cv_transition(t), cv_process_noise(t, self.cfg.sigma_a_mps2)
        self.x, self.p = f @ self.x, f @ self.p @ f.T + q
        lam_z, eta_z = _reference_information(z, r, self.prior.mean, self.prior.sigmas)
        info_pred = np.linalg.inv(self.p)
        self.p = np.linalg.inv(info_pred + lam_z)
        self.x = self.p @ (info_pred @ self.x + eta_z)


def test_central_tracker_equals_the_numpy_information_filter():
    """A walking target's MAP estimates, one per frame, some seen by one node
    (rank-3 measurement information, the eigenvalue clipping path)."""
    rng = np.random.default_rng(9)
    prior, cfg = GaussianPrior(), CentralConfig(gate_probability=1.0 - 1e-12)
    tracker = CentralTracker(cfg, prior_mean=prior.mean, prior_sigmas=prior.sigmas)
    ref = _ReferenceTracker(cfg, prior)
    stream = FrameStream(list(NETWORK), SQUARE, config=stream_config(solver="scalar"))
    truth = np.array([-1.5, 2.0, 0.4, 0.3])
    clipped = 0
    for k in range(50):
        truth = cv_transition(0.15) @ truth
        dets = [predict_measurements(truth, pose)[None] + rng.normal(size=(1, 3)) * [0.05, 0.1, 0.05]
                for pose in SQUARE]
        for d in dets:
            d[:, 1] = np.clip(wrap_angle(d[:, 1]), -np.pi, np.pi)
        if k % 4 == 3:
            dets = [dets[0]] + [np.zeros((0, 3))] * 3
        u = stream.push(0.15 * (k + 1), dets)
        assert u.ok and u.success[0]
        lam, _ = _reference_information(u.state[0], u.covariance[0], prior.mean, prior.sigmas)
        clipped += np.linalg.eigvalsh(lam).min() < 1e-9
        out = tracker.step(u.state[:1], u.covariance[:1], 0.15)  # the first group: one target
        ref.step(u.state[0], u.covariance[0], 0.15)
        assert len(out) == 1
        (_, x, p), = out
        np.testing.assert_allclose(x, ref.x, rtol=0, atol=1e-9)
        np.testing.assert_allclose(p, ref.p, rtol=1e-9, atol=1e-12)
        info, eta = measurement_information(u.state[0], u.covariance[0], prior.mean, prior.sigmas)
        np.testing.assert_allclose(info, lam, rtol=1e-9, atol=1e-9 * np.abs(lam).max())
    assert clipped >= 10
