"""TDM-MIMO Doppler de-aliasing (issue 14, Build 5): a target faster than the
unambiguous speed keeps its Doppler, its angle and its heading through the
chain and the EKF."""

import dataclasses

import numpy as np
import pytest

from mmsnap_graph.data.radar_config import TABLE_I
from mmsnap_graph.errors import ConfigurationError
from mmsnap_graph.radar.chain import (
    ChainConfig,
    doppler_near_limit,
    point_cloud_of_cube,
    process_cubes,
    unambiguous_speed_mps,
)
from mmsnap_graph.radar.cluster import ClusterConfig
from mmsnap_graph.radar.spectrum import estimate_omega_dealiased, wrap_hypotheses
from mmsnap_graph.sim.cube import scatterer_amplitude, synthesize_cube, synthesize_cubes
from mmsnap_graph.tracking.ekf import EkfConfig, ekf_update, track_centroids, wrap_innovation

#: Table I chirps at 20 fps (so that a 6-9 m/s target stays in view for a second).
FAST = dataclasses.replace(TABLE_I, frame_period_s=0.05)


def _fast_targets(n, seed):
    rng = np.random.default_rng(seed)
    for _ in range(n):
        r, th, vr = rng.uniform(3, 9), rng.uniform(-0.8, 0.8), -rng.uniform(6.0, 9.0)
        p = np.array([[r * np.sin(th), r * np.cos(th)]])
        cube = synthesize_cube(FAST, p, vr * p / r, scatterer_amplitude(FAST, 1.0, r), rng=rng)
        yield cube, np.pi * np.sin(th), vr


def _strongest(cube, chain):
    (r, w, v, s), _ = point_cloud_of_cube(cube, FAST, chain)
    j = int(np.argmax(s))
    return w[j], v[j]


def test_fast_target_doppler_and_angle_recovered():
    assert FAST.max_doppler_mps == pytest.approx(5.479, abs=1e-3)
    err_w = {0: [], 1: []}
    err_v = {0: [], 1: []}
    for cube, omega, vr in _fast_targets(20, seed=3):
        for k in (0, 1):
            w, v = _strongest(cube, ChainConfig(doppler_wraps=k))
            err_w[k].append(abs(w - omega))
            err_v[k].append(abs(v - vr))
    # Without de-aliasing: Doppler off by 2 v_max, angle off by ~0.4 rad
    # (the TDM correction uses the aliased speed; issue 14 measured 0.40 rad).
    assert np.median(err_v[0]) == pytest.approx(2 * FAST.max_doppler_mps, abs=0.05)
    assert np.median(err_w[0]) > 0.3
    # With it: Doppler within 5 cm/s, angle back to the slow-target accuracy.
    assert np.max(err_v[1]) < 0.05
    assert np.median(err_w[1]) < 0.02 and np.max(err_w[1]) < 0.06


def test_slow_targets_are_not_wrapped():
    rng = np.random.default_rng(11)
    for _ in range(15):
        r, th, vr = rng.uniform(3, 9), rng.uniform(-0.8, 0.8), rng.uniform(-4.5, 4.5)
        p = np.array([[r * np.sin(th), r * np.cos(th)]])
        cube = synthesize_cube(FAST, p, vr * p / r, scatterer_amplitude(FAST, 0.5, r), rng=rng)
        _, v = _strongest(cube, ChainConfig())
        assert abs(v - vr) < 0.05


def test_hypotheses_and_ties():
    np.testing.assert_array_equal(wrap_hypotheses(2), [0, -1, 1, -2, 2])
    np.testing.assert_array_equal(wrap_hypotheses(0), [0])
    # A single-transmitter azimuth array cannot tell wraps apart: every
    # hypothesis ties and the slowest speed is kept.
    one_tx = dataclasses.replace(TABLE_I, tx_azimuth_half_wl=(0.0, 0.0, 0.0),
                                 tx_elevation_half_wl=(0.0, 1.0, 2.0))
    snap = np.exp(1j * 0.7 * np.arange(one_tx.n_virtual))[None, :].astype(np.complex64)
    _, _, v = estimate_omega_dealiased(snap, np.array([3.0]), one_tx, max_wraps=2)
    assert v[0] == pytest.approx(3.0)


def test_near_limit_flag_and_unambiguous_speed():
    chain = ChainConfig(doppler_wraps=1, near_limit_fraction=0.9)
    u = unambiguous_speed_mps(TABLE_I, chain)
    assert u == pytest.approx(3 * TABLE_I.max_doppler_mps)
    assert unambiguous_speed_mps(TABLE_I, ChainConfig(doppler_wraps=0)) == pytest.approx(
        TABLE_I.max_doppler_mps)
    flags = doppler_near_limit(np.array([0.0, 0.89 * u, -0.95 * u, 1.2 * u]), TABLE_I, chain)
    np.testing.assert_array_equal(flags, [False, False, True, True])


@pytest.mark.parametrize("kwargs", [{"doppler_wraps": -1}, {"doppler_wraps": 1.5},
                                    {"doppler_wraps": True}, {"near_limit_fraction": 0.0},
                                    {"dealias_min_snr_db": float("nan")}])
def test_dealias_options_are_checked(kwargs):
    with pytest.raises(ConfigurationError, match=next(iter(kwargs))):
        ChainConfig(**kwargs)


def _approach(n_frames=20, seed=4):
    rng = np.random.default_rng(seed)
    t = np.arange(n_frames) * FAST.frame_period_s
    u = np.array([np.sin(0.3), np.cos(0.3)])
    speed = -6.5                                   # approaching, beyond +-5.48 m/s
    pos = [((10.0 + speed * ti) * u)[None, :] for ti in t]
    vel = [(speed * u)[None, :] for _ in t]
    amp = [scatterer_amplitude(FAST, 5.0, np.hypot(*p[0]))[None] for p in pos]
    return synthesize_cubes(FAST, pos, vel, amp, rng=rng), speed


def test_approaching_target_is_tracked_as_approaching():
    cubes, speed = _approach()
    chain = ChainConfig(cluster=ClusterConfig(point_targets=True))
    res = process_cubes(cubes, FAST, chain)
    assert len(res.centroids) >= 18
    np.testing.assert_allclose(res.centroids.doppler_mps, speed, atol=0.1)
    assert res.doppler_near_limit.shape == (len(res.point_cloud),)
    ekf = EkfConfig(frame_period_s=FAST.frame_period_s,
                    doppler_wrap_mps=unambiguous_speed_mps(FAST, chain))
    tracks = track_centroids(res.centroids, ekf)
    assert tracks.track_ids.size == 1
    x = tracks.state
    radial = np.sum(x[:, :2] * x[:, 2:], axis=1) / np.hypot(x[:, 0], x[:, 1])
    np.testing.assert_allclose(radial, speed, atol=0.3)
    # Without de-aliasing the same target reads as receding.
    off = process_cubes(cubes, FAST, ChainConfig(doppler_wraps=0,
                                                 cluster=ClusterConfig(point_targets=True)))
    assert np.all(off.centroids.doppler_mps > 0)


def test_ekf_wraps_the_doppler_innovation():
    u = FAST.max_doppler_mps
    nu = wrap_innovation(np.array([[0.0, 0.0, 2 * u - 0.1], [0.0, 7.0, -2 * u + 0.2]]), u)
    np.testing.assert_allclose(nu[:, 2], [-0.1, 0.2], atol=1e-12)
    np.testing.assert_allclose(nu[:, 1], [0.0, 7.0 - 2 * np.pi])
    # A track approaching at 6.5 m/s, an aliased measurement (+4.46 m/s).
    x = np.array([0.0, 8.0, 0.0, -6.5])
    p = np.diag([0.01, 0.01, 0.1, 0.1])
    z = np.array([8.0, 0.0, -6.5 + 2 * u])
    r = np.diag([0.05, 0.1, 0.2]) ** 2
    x_wrap, _, d2_wrap = ekf_update(x, p, z, r, doppler_wrap_mps=u)
    x_raw, _, d2_raw = ekf_update(x, p, z, r)
    assert x_wrap[3] == pytest.approx(-6.5, abs=1e-6) and d2_wrap < 1e-9
    assert x_raw[3] > -3.0 and d2_raw > 100
    with pytest.raises(ConfigurationError, match="doppler_wrap_mps"):
        EkfConfig(doppler_wrap_mps=0.0)
