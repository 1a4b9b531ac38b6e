"""Raw-ADC cube synthesis: the phases of each axis, noise and SNR scaling,
clutter, batching and the error branches (independent of the signal chain)."""

import numpy as np
import pytest

from mmsnap_graph.errors import ConfigurationError, ValidationError
from mmsnap_graph.data.radar_config import TABLE_I
from mmsnap_graph.sim.cube import (
    post_fft_snr_db,
    scatterer_amplitude,
    synthesize_cube,
    synthesize_cubes,
)

from _shared import SMALL_RADAR


def _single(config, p, v, amp=1.0):
    return synthesize_cube(config, np.array([p]), np.array([v]), np.array([amp]),
                           rng=np.random.default_rng(0), noise_std=0.0)


@pytest.mark.parametrize("config", [TABLE_I, SMALL_RADAR], ids=["table1", "256x128x2tx"])
def test_single_scatterer_phases(config):
    p = np.array([1.5, 4.0])
    v = np.array([0.3, -0.8])
    cube = _single(config, p, v, 0.7)
    assert cube.shape == config.cube_shape and cube.dtype == np.complex64
    r = np.hypot(*p)
    vr = v @ p / r
    sin_t = p[0] / r
    # Fast time: constant beat frequency 2 (slope r + fc vr) / c.
    fb = 2 * (config.slope_hz_per_s * r + config.carrier_hz * vr) / 299_792_458.0
    ratio = cube[1:, 0, 0] / cube[:-1, 0, 0]
    np.testing.assert_allclose(np.angle(ratio), np.angle(np.exp(2j * np.pi * fb / config.sample_rate_hz)),
                               atol=1e-4)
    np.testing.assert_allclose(np.abs(cube), 0.7, rtol=1e-5)
    # Slow time: the same channel advances by 4 pi vr T_loop / lambda per loop.
    step = 4 * np.pi * vr * config.loop_period_s / config.wavelength_m
    ratio = cube[0, 1:, 0] / cube[0, :-1, 0]
    np.testing.assert_allclose(np.angle(ratio), np.angle(np.exp(1j * step)), atol=1e-4)
    # Space: channel (tx, rx) has phase pi (tx + rx) sin(theta) plus the TDM
    # Doppler phase of transmitter tx firing tx chirp periods into the loop.
    pos = config.virtual_azimuth_half_wl
    tx = np.repeat(np.arange(config.n_tx), config.n_rx)
    tdm = 4 * np.pi * vr * tx * config.chirp_period_s / config.wavelength_m
    want = np.exp(1j * (np.pi * pos * sin_t + tdm))
    got = cube[0, 0, :] / cube[0, 0, 0]
    np.testing.assert_allclose(got, want, atol=1e-4)


def test_peak_lands_in_the_right_range_doppler_cell():
    config = TABLE_I
    p, v = np.array([-2.0, 6.0]), np.array([0.0, 1.2])
    cube = _single(config, p, v)
    spec = np.abs(np.fft.fftshift(np.fft.fft(np.fft.fft(cube, axis=0), axis=1), axes=1)) ** 2
    k, l = np.unravel_index(np.argmax(spec.sum(2)), spec.shape[:2])
    r = np.hypot(*p)
    assert abs(k * config.range_resolution_m - r) <= config.range_resolution_m
    vr = v @ p / r
    assert abs((l - config.n_loops // 2) * config.doppler_resolution_mps - vr) \
        <= config.doppler_resolution_mps


def test_noise_variance_and_post_fft_snr():
    config = TABLE_I
    rng = np.random.default_rng(1)
    noise = synthesize_cube(config, np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0),
                            rng=rng, noise_std=2.0)
    n = noise.size
    # E|n|^2 = 4; the sample mean has relative std 1/sqrt(n).
    assert abs(np.mean(np.abs(noise) ** 2) / 4.0 - 1) < 5 / np.sqrt(n)
    assert abs(np.mean(noise.real ** 2) / 2.0 - 1) < 5 * np.sqrt(2 / n)
    # Radar equation: a 0.5 m^2 torso at 5 m gives 29 dB per channel after
    # the 2D FFT, and 40 log10(2) = 12 dB less at twice the range.
    a5 = scatterer_amplitude(config, 0.5, 5.0, noise_std=2.0)
    a10 = scatterer_amplitude(config, 0.5, 10.0, noise_std=2.0)
    assert post_fft_snr_db(config, a5, 2.0) == pytest.approx(20 - 3.0103 + 12.0412, abs=1e-3)
    assert post_fft_snr_db(config, a5, 2.0) - post_fft_snr_db(config, a10, 2.0) \
        == pytest.approx(40 * np.log10(2), abs=1e-9)
    # Measured: peak power over mean noise power in the 2D FFT, target on a bin.
    r_on_bin = 200 * config.range_resolution_m
    amp = scatterer_amplitude(config, 0.5, 5.0, noise_std=1.0)
    cube = synthesize_cube(config, np.array([[0.0, r_on_bin]]), np.zeros((1, 2)),
                           np.array([amp]), rng=rng, noise_std=1.0)
    # Zero velocity and R on range bin 200 exactly: no leakage, so the peak
    # holds the full coherent gain.
    spec = np.abs(np.fft.fft(np.fft.fft(cube, axis=0), axis=1)) ** 2
    peak = spec[200, 0, :].mean()
    noise_floor = np.median(spec[300:, 10:, :]) / np.log(2)  # exponential: median = ln2 mean
    measured_db = 10 * np.log10(peak / noise_floor)
    assert measured_db == pytest.approx(post_fft_snr_db(config, amp, 1.0), abs=0.5)


def test_clutter_is_static_and_identical_between_frames():
    config = SMALL_RADAR
    clutter = (np.array([[1.0, 3.0], [-2.0, 7.0]]), np.array([2.0, 1.0 + 1.0j]))
    cubes = synthesize_cubes(config, [np.zeros((0, 2))] * 2, [np.zeros((0, 2))] * 2,
                             [np.zeros(0)] * 2, rng=np.random.default_rng(0), noise_std=0.0,
                             clutter=clutter)
    np.testing.assert_array_equal(cubes[0], cubes[1])
    # Zero Doppler: every loop of a channel is the same.
    np.testing.assert_allclose(cubes[0], cubes[0][:, :1, :].repeat(config.n_loops, 1), atol=1e-5)
    single = synthesize_cube(config, np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0),
                             rng=np.random.default_rng(0), noise_std=0.0, clutter=clutter)
    np.testing.assert_allclose(single, cubes[0], atol=1e-5)


def test_batch_matches_single_and_accepts_arrays():
    config = SMALL_RADAR
    rng = np.random.default_rng(3)
    pos = rng.uniform([-3, 1], [3, 8], (4, 5, 2))
    vel = rng.normal(0, 1, (4, 5, 2))
    amp = rng.uniform(0.1, 1, (4, 5))
    batch = synthesize_cubes(config, pos, vel, amp, rng=rng, noise_std=0.0)
    assert batch.shape == (4, *config.cube_shape)
    for f in range(4):
        one = synthesize_cube(config, pos[f], vel[f], amp[f], rng=rng, noise_std=0.0)
        np.testing.assert_allclose(batch[f], one, atol=1e-5)
    # Same seed, same noise; ragged per-frame lists work.
    lists = ([pos[0], pos[1][:2]], [vel[0], vel[1][:2]], [amp[0], amp[1][:2]])
    a = synthesize_cubes(config, *lists, rng=np.random.default_rng(9), noise_std=1.0)
    b = synthesize_cubes(config, *lists, rng=np.random.default_rng(9), noise_std=1.0)
    np.testing.assert_array_equal(a, b)
    out = np.empty((2, *config.cube_shape), np.complex64)
    c = synthesize_cubes(config, *lists, rng=np.random.default_rng(9), noise_std=1.0, out=out)
    assert c is out
    np.testing.assert_array_equal(c, a)


def test_scatterer_beyond_max_range_is_dropped():
    config = TABLE_I
    cube = _single(config, np.array([0.0, config.max_range_m + 0.5]), np.zeros(2))
    assert not np.any(cube)


def test_errors():
    rng = np.random.default_rng(0)
    c = TABLE_I
    with pytest.raises(ValidationError, match=r"positions_local_m must have shape \(M, 2\)"):
        synthesize_cube(c, np.zeros((2, 3)), np.zeros((2, 2)), np.ones(2), rng=rng)
    with pytest.raises(ValidationError, match=r"velocities_local_mps must have shape \(2, 2\)"):
        synthesize_cube(c, np.ones((2, 2)), np.zeros((3, 2)), np.ones(2), rng=rng)
    with pytest.raises(ValidationError, match=r"amplitudes must have shape \(2,\)"):
        synthesize_cube(c, np.ones((2, 2)), np.zeros((2, 2)), np.ones(3), rng=rng)
    with pytest.raises(ValidationError, match="amplitudes must be finite"):
        synthesize_cube(c, np.ones((1, 2)), np.zeros((1, 2)), np.array([np.nan]), rng=rng)
    with pytest.raises(ValidationError, match="amplitudes must be numeric"):
        synthesize_cube(c, np.ones((1, 2)), np.zeros((1, 2)), np.array(["a"]), rng=rng)
    with pytest.raises(ValidationError, match="positions_local_m must be finite"):
        synthesize_cube(c, np.array([[np.inf, 1.0]]), np.zeros((1, 2)), np.ones(1), rng=rng)
    with pytest.raises(ValidationError, match="range 0"):
        synthesize_cube(c, np.zeros((1, 2)), np.zeros((1, 2)), np.ones(1), rng=rng)
    with pytest.raises(ValidationError, match="noise_std must be finite and >= 0"):
        synthesize_cube(c, np.ones((1, 2)), np.zeros((1, 2)), np.ones(1), rng=rng, noise_std=-1)
    with pytest.raises(ValidationError, match="clutter must be a pair"):
        synthesize_cube(c, np.ones((1, 2)), np.zeros((1, 2)), np.ones(1), rng=rng, clutter=3)
    with pytest.raises(ConfigurationError, match="config must be a RadarConfig"):
        synthesize_cube({"n_samples": 4}, np.ones((1, 2)), np.zeros((1, 2)), np.ones(1), rng=rng)
    with pytest.raises(ValidationError, match="must cover the same frames"):
        synthesize_cubes(c, [np.ones((1, 2))], [], [np.ones(1)], rng=rng)
    with pytest.raises(ValidationError, match="frame 1: positions_local_m"):
        synthesize_cubes(SMALL_RADAR, [np.ones((1, 2)), np.ones((1, 3))], [np.zeros((1, 2))] * 2,
                         [np.ones(1)] * 2, rng=rng)
    with pytest.raises(ValidationError, match="out must be complex64"):
        synthesize_cubes(SMALL_RADAR, [np.ones((1, 2))], [np.zeros((1, 2))], [np.ones(1)], rng=rng,
                         out=np.zeros((1, 2, 3), np.complex64))
    with pytest.raises(ValidationError, match="rcs_m2 must be >= 0"):
        scatterer_amplitude(c, -1.0, 5.0)
    with pytest.raises(ValidationError, match="range_m must be > 0"):
        scatterer_amplitude(c, 1.0, 0.0)
