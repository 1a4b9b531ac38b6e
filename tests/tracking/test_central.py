"""Central Kalman filter over one-shot estimates (mmsnap_graph.tracking.central)."""

import numpy as np
import pytest

from factors.models import measurement_model
from _fusion import solved
from mmsnap_graph.data.noise import GaussianPrior, MeasurementNoise
from mmsnap_graph.errors import ConfigurationError, ValidationError
from mmsnap_graph.evaluation import chi2_mean_interval, nees
from mmsnap_graph.fusion.recording.sequence import fuse_recording
from mmsnap_graph.sim import simulate_recording
from mmsnap_graph.tracking.central import (
    CentralConfig,
    CentralTracker,
    FixedLagTracker,
    cv_predict_floats,
    measurement_information,
    track_fused,
)

from _shared import POSES_B, POSES_C
from mmsnap_graph.sim import SimulationOptions
from _fusion import config

T = 0.15
SIGMA_A = 0.2
POSES = {"B": POSES_B, "C": POSES_C}


def _cv_trajectory(rng, n, start, box_m, sigma_a=SIGMA_A):
    """Constant velocity with piecewise-constant white acceleration (exactly
    the filter's Q), redrawn until it stays within ``box_m`` of its start."""
    start = np.asarray(start, float)
    while True:
        a = rng.normal(0.0, sigma_a, (n, 2))
        x = np.zeros((n, 4))
        x[0] = start
        for k in range(1, n):
            x[k, :2] = x[k - 1, :2] + x[k - 1, 2:] * T + a[k] * T**2 / 2
            x[k, 2:] = x[k - 1, 2:] + a[k] * T
        if np.all(np.abs(x[:, :2] - start[:2]) < box_m):
            return x


def _run(rng, poses, start, noise, prior, config, n_runs, n_frames, box_m=1.5):
    out = np.zeros((n_runs, n_frames))
    for run in range(n_runs):
        x = _cv_trajectory(rng, n_frames, start, box_m, config.sigma_a_mps2)
        h, _ = measurement_model(x[:, None, :], poses)
        z = h + rng.standard_normal(h.shape) * noise.sigmas
        z[..., 1] = np.clip(z[..., 1], -np.pi, np.pi)
        res = solved(poses, z, solver="vectorized", noise=noise, prior=prior)
        assert res.success.all()
        tracker = CentralTracker(config, prior_mean=None if prior is None else prior.mean,
                                 prior_sigmas=None if prior is None else prior.sigmas)
        for k in range(n_frames):
            tracks = tracker.step(res.state[k:k + 1], res.covariance[k:k + 1])
            assert len(tracks) == 1
            _, xe, pe = tracks[0]
            out[run, k] = nees((xe - x[k])[None], pe[None])[0]
    return out


@pytest.mark.slow
@pytest.mark.parametrize("net, start", [("B", [0.5, 4.0, 0.0, 0.0]), ("C", [1.2, 3.5, 0.0, 0.0])])
def test_central_tracker_nees_is_consistent(net, start):
    """Monte Carlo NEES (Bar-Shalom's ANEES) on simulated CV targets fused by
    MAP one-shot estimates. The spatial-frequency sigma is 0.1 rad in the
    simulation and the fusion: with the paper's pi / 4 the one-shot posterior
    is sometimes bimodal (mirror image across the line through the radars)
    and no Gaussian covariance is honest there. The configuration-C target
    stays 0.4 m or more off the line through the radars: right on it the
    Laplace covariance of the curved posterior is optimistic (ANEES about 5.5
    over the frames of a crossing)."""
    rng = np.random.default_rng(20)
    noise = MeasurementNoise(omega_rad=0.1)
    n_runs, n_frames = 30, 50
    values = _run(rng, POSES[net], start, noise, GaussianPrior(),
                  CentralConfig(gate_probability=0.999999), n_runs, n_frames, box_m=0.8)
    anees = values[:, 5:].mean(axis=0)  # per frame, over runs, after the start-up
    lo, hi = chi2_mean_interval(4, n_runs, confidence=0.95)
    assert np.mean((anees >= lo) & (anees <= hi)) > 0.8
    lo_all, hi_all = 3.5, 4.7  # all frames pooled, correlated in time
    assert lo_all < values[:, 5:].mean() < hi_all


def test_removing_the_prior_keeps_a_strong_prior_from_being_counted_every_frame():
    """A nearly constant velocity of 0.5 m/s and a velocity prior of 0.2 m/s
    around zero: fed as they are, the MAP estimates (each shrunk toward zero
    by about 45 %) drag the track's velocity down frame after frame while its
    covariance shrinks; with the prior removed the track stays consistent."""
    noise = MeasurementNoise(omega_rad=0.1)
    strong = GaussianPrior(mean=np.zeros(4), sigmas=[3.0, 3.0, 0.2, 0.2])
    start = [-0.5, 4.0, 0.5, 0.0]
    kw = dict(sigma_a_mps2=0.01, gate_probability=0.999999)
    kept = _run(np.random.default_rng(21), POSES["B"], start, noise, strong,
                CentralConfig(remove_prior=True, **kw), 10, 40, box_m=4.0)
    naive = _run(np.random.default_rng(21), POSES["B"], start, noise, strong,
                 CentralConfig(remove_prior=False, **kw), 10, 40, box_m=4.0)
    assert 3.0 < kept[:, 5:].mean() < 5.0
    assert naive[:, 5:].mean() > 6.0
    assert naive[:, 5:].mean() > 1.5 * kept[:, 5:].mean()


def test_measurement_information_undoes_the_prior_exactly_for_a_linear_problem():
    rng = np.random.default_rng(22)
    a = rng.normal(size=(4, 6))
    lam_l = a @ a.T
    x_ml = rng.normal(size=4)
    m = rng.normal(size=4)
    s = np.array([3.0, 3.0, 3.5, 3.5])
    lam_p = np.diag(1 / s**2)
    p_map = np.linalg.inv(lam_l + lam_p)
    x_map = p_map @ (lam_l @ x_ml + lam_p @ m)
    info, eta = measurement_information(x_map, p_map, m, s)
    np.testing.assert_allclose(info, lam_l, rtol=1e-9, atol=1e-10)
    np.testing.assert_allclose(eta, lam_l @ x_ml, rtol=1e-9, atol=1e-10)
    info, eta = measurement_information(x_ml, np.linalg.inv(lam_l))
    np.testing.assert_allclose(info, lam_l, rtol=1e-9)
    # A direction that only the prior determined: clipped to zero, not negative.
    lam_l[:, 3] = lam_l[3, :] = 0.0
    p_map = np.linalg.inv(lam_l + lam_p)
    info, _ = measurement_information(np.zeros(4), p_map, m, s)
    assert np.linalg.eigvalsh(info).min() >= 0.0
    np.testing.assert_allclose(info[3], 0.0, atol=1e-9)


def test_tracks_two_targets_of_a_simulated_recording():
    """Walking humans turn harder than the paper's sigma_a = 0.2 m/s^2 allows
    (and the simulated centroids are noisier in range than the fusion's
    0.035 m), so this run uses sigma_a = 2 m/s^2 and a wide gate."""
    rec = simulate_recording("B", "random",
                             SimulationOptions(physics=None, n_targets=2, known_poses=True, centroid_p_miss=0.1),
                             levels=("centroids",), n_frames=120, seed=5)
    fused = fuse_recording(rec, config())
    cfg = CentralConfig(frame_period_s=rec.frame_period_s, sigma_a_mps2=2.0, gate_probability=0.999999)
    tracks = track_fused(fused, cfg)
    assert tracks.frame.min() == fused.frame.min() and tracks.frame.max() == fused.frame.max()
    long_tracks = [t for t in tracks.track_ids if len(tracks.track(t)) > 80]
    assert len(long_tracks) == 2
    for tid in long_tracks:
        tr = tracks.track(tid)
        # Which target is it? The one nearest at its first frame.
        dists = [np.linalg.norm(rec.truth.target(t)[1][tr.frame[0], :2] - tr.state[0, :2]) for t in (0, 1)]
        _, truth = rec.truth.target(int(np.argmin(dists)))
        err = tr.state[10:] - truth[tr.frame[10:]]
        assert np.sqrt(np.mean(np.sum(err[:, :2] ** 2, axis=1))) < 0.2
        assert np.sqrt(np.mean(np.sum(err[:, 2:] ** 2, axis=1))) < 0.5


def test_tracks_end_after_misses_and_new_estimates_start_tracks():
    tracker = CentralTracker(CentralConfig(max_misses=2))
    p = np.diag([0.01, 0.01, 0.04, 0.04])
    tracker.step([[0.0, 3.0, 0.0, 0.0]], [p])
    assert len(tracker.tracks) == 1
    out = tracker.step([[0.0, 3.0, 0.0, 0.0], [3.0, 1.0, 0.0, 0.0]], [p, p])
    assert sorted(t[0] for t in out) == [0, 1]
    tracker.step(np.zeros((0, 4)), np.zeros((0, 4, 4)))
    assert len(tracker.tracks) == 2
    tracker.step(np.zeros((0, 4)), np.zeros((0, 4, 4)))
    assert tracker.tracks == []
    # A new track's velocity uncertainty is at least init_velocity_sigma_mps.
    tracker.step([[0.0, 3.0, 0.0, 0.0]], [p])
    assert tracker.tracks[0][2][2, 2] == pytest.approx(1.0)


def test_track_fused_without_successful_frames_is_empty():
    rec = simulate_recording("B", "straight", SimulationOptions(physics=None, known_poses=True),
                             levels=("centroids",), n_frames=5, seed=1)
    fused = fuse_recording(rec, config())
    import dataclasses

    none_ok = dataclasses.replace(fused, success=np.zeros(len(fused), dtype=bool))
    assert len(track_fused(none_ok)) == 0


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(frame_period_s=0.0), "frame_period_s"),
        (dict(sigma_a_mps2=-1.0), "sigma_a_mps2"),
        (dict(gate_probability=1.0), "gate_probability"),
        (dict(max_misses=0), "max_misses"),
        (dict(init_velocity_sigma_mps=np.nan), "init_velocity_sigma_mps"),
    ],
)
def test_invalid_config_raises(kwargs, match):
    with pytest.raises(ConfigurationError, match=match):
        CentralConfig(**kwargs)


def test_invalid_step_input_raises():
    tracker = CentralTracker()
    with pytest.raises(ValidationError, match=r"covariances must have shape \(1, 4, 4\)"):
        tracker.step([[0.0, 3.0, 0.0, 0.0]], np.eye(4))
    with pytest.raises(ValidationError, match="states must be finite"):
        tracker.step([[np.nan, 3.0, 0.0, 0.0]], [np.eye(4)])
    with pytest.raises(ValidationError, match="prior_mean and prior_sigmas go together"):
        CentralTracker(prior_mean=np.zeros(4))


@pytest.mark.slow
def test_fixed_lag_smoother_is_consistent_and_follows_the_kalman_filter():
    """The GTSAM fixed-lag smoother's newest state is the Kalman filter's
    estimate up to the process-noise form (continuous white noise in the
    factor, discrete in the filter)."""
    rng = np.random.default_rng(23)
    noise = MeasurementNoise(omega_rad=0.1)
    prior = GaussianPrior()
    # sigma_a pinned to the simulated targets' (SIGMA_A): the filter/smoother
    # gap from the two process-noise forms grows with it, and 5e-3 assumes it.
    cfg = CentralConfig(gate_probability=0.999999, sigma_a_mps2=SIGMA_A)
    n_runs, n_frames = 12, 40
    nees_fl = np.zeros((n_runs, n_frames))
    for run in range(n_runs):
        x = _cv_trajectory(rng, n_frames, [0.5, 4.0, 0.0, 0.0], 0.8)
        h, _ = measurement_model(x[:, None, :], POSES["B"])
        z = h + rng.standard_normal(h.shape) * noise.sigmas
        res = solved(POSES["B"], z, solver="vectorized", noise=noise, prior=prior)
        kf = CentralTracker(cfg, prior_mean=prior.mean, prior_sigmas=prior.sigmas)
        fl = FixedLagTracker(cfg, lag_s=1.0, prior_mean=prior.mean, prior_sigmas=prior.sigmas)
        for k in range(n_frames):
            # Every fourth frame without an estimate: prediction only.
            sl = slice(k, k + 1) if k % 4 != 3 or k == 0 else slice(0, 0)
            (_, xk, pk), = kf.step(res.state[sl], res.covariance[sl])
            (_, xf, pf), = fl.step(res.state[sl], res.covariance[sl])
            np.testing.assert_allclose(xf, xk, atol=5e-3)
            np.testing.assert_allclose(np.sqrt(np.diag(pf)), np.sqrt(np.diag(pk)), rtol=0.1)
            nees_fl[run, k] = nees((xf - x[k])[None], pf[None])[0]
    assert 3.0 < nees_fl[:, 5:].mean() < 5.0


def test_fixed_lag_smoother_waits_for_a_first_estimate_and_checks_input():
    fl = FixedLagTracker()
    assert fl.step(np.zeros((0, 4)), np.zeros((0, 4, 4))) == []
    out = fl.step([[0.0, 3.0, 0.5, 0.0]], [np.diag([0.01, 0.01, 0.04, 0.04])])
    assert len(out) == 1 and out[0][2][2, 2] == pytest.approx(1.0)  # the velocity floor
    with pytest.raises(ValidationError, match=r"covariances must have shape \(1, 4, 4\)"):
        fl.step([[0.0, 3.0, 0.0, 0.0]], np.eye(4))
    with pytest.raises(ConfigurationError, match="lag_s"):
        FixedLagTracker(lag_s=0.0)
    with pytest.raises(ValidationError, match="prior_mean and prior_sigmas go together"):
        FixedLagTracker(prior_sigmas=np.ones(4))


def test_the_float_prediction_is_the_constant_velocity_model_in_numpy():
    """cv_predict_floats (written out entry by entry) against F x and
    F P F^T + Q of factors.motion in numpy, for random covariances (not
    symmetric to the bit: the result is symmetrized, exactly symmetric) and
    periods, to 1e-12 relative."""
    from factors.motion import cv_process_noise, cv_transition

    rng = np.random.default_rng(5)
    for _ in range(20):
        t = float(rng.uniform(0.01, 2.0))
        a = rng.normal(0, 1, (4, 4))
        p = a @ a.T + 1e-3 * rng.normal(0, 1, (4, 4))   # slightly asymmetric
        x = rng.normal(0, 3, 4)
        q = cv_process_noise(t, float(rng.uniform(0.1, 3.0)))
        got_x, got_p = cv_predict_floats(x.tolist(), p.ravel().tolist(), t, q.ravel().tolist())
        f = cv_transition(t)
        want = f @ (0.5 * (p + p.T)) @ f.T + q
        np.testing.assert_allclose(got_x, f @ x, rtol=1e-12, atol=1e-12)
        got_p = np.array(got_p).reshape(4, 4)
        np.testing.assert_allclose(got_p, want, rtol=1e-12, atol=1e-12 * np.abs(want).max())
        np.testing.assert_array_equal(got_p, got_p.T)
