"""Per-node signal chain: FFTs, TDM correction, OS-CFAR, point clouds, torso
clustering, degenerate frames and configuration errors."""

import dataclasses

import numpy as np
import pytest

from mmsnap_graph.errors import ConfigurationError, ValidationError
from mmsnap_graph.radar.cfar import (
    CfarConfig,
    os_cfar_2d,
    os_cfar_alpha,
    os_cfar_cells,
    os_cfar_noise_scale,
)
from mmsnap_graph.radar.chain import (
    ChainConfig,
    detect_frame,
    point_cloud_of_cube,
    process_cubes,
    doppler_near_limit,
    unambiguous_speed_mps,
    DEFAULT_MIN_RANGE_M,
)
from mmsnap_graph.radar.cluster import ClusterConfig, cluster_labels, torso_centroids
from mmsnap_graph.data.radar_config import TABLE_I
from mmsnap_graph.radar.spectrum import (
    check_cube,
    doppler_of_bin,
    estimate_omega,
    parabolic_offset,
    range_doppler,
    window,
)
from mmsnap_graph.data.recording import Detections
from mmsnap_graph.data.results import Status
from mmsnap_graph.sim.cube import scatterer_amplitude, synthesize_cube, synthesize_cubes
from mmsnap_graph.tracking.ekf import EkfConfig, track_centroids

from _shared import SMALL_RADAR

#: Another chirp configuration: 256 samples, 128 loops, 2 Tx (8-element azimuth array).
CONFIGS = pytest.mark.parametrize("config", [TABLE_I, SMALL_RADAR], ids=["table1", "256x128x2tx"])


# ---------------------------------------------------------------- spectrum
def test_range_doppler_equals_textbook_order():
    config = SMALL_RADAR
    rng = np.random.default_rng(0)
    cube = (rng.standard_normal(config.cube_shape) + 1j * rng.standard_normal(config.cube_shape)
            + 3.0).astype(np.complex64)
    spec, power = range_doppler(cube, config, range_window="hamming", doppler_window="hann")
    # Reference in float64: range FFT, subtract the loop mean, window, Doppler FFT.
    x = cube.astype(np.complex128)
    wr = window("hamming", config.n_samples).astype(float)
    wd = window("hann", config.n_loops).astype(float)
    r = np.fft.fft(x * wr[:, None, None], axis=0)
    r = r - r.mean(axis=1, keepdims=True)
    ref = np.fft.fft(r * wd[None, :, None], axis=1)
    scale = np.abs(ref).max()
    np.testing.assert_allclose(spec, ref, atol=1e-5 * scale)
    np.testing.assert_allclose(power, np.sum(np.abs(ref) ** 2, axis=2), rtol=1e-3,
                               atol=1e-9 * scale**2)
    # range_bins crops the same spectrum.
    spec2, _ = range_doppler(cube, config, range_window="hamming", range_bins=slice(5, 50))
    np.testing.assert_allclose(spec2, spec[5:50], atol=1e-5 * scale)


def test_parabolic_offset_and_doppler_wrap():
    # Exact for a parabola with vertex at 0.3.
    xs = np.array([-1.0, 0.0, 1.0])
    y = -(xs - 0.3) ** 2
    assert parabolic_offset(y[0], y[1], y[2]) == pytest.approx(0.3, abs=1e-12)
    assert parabolic_offset(0.0, 0.0, 0.0) == 0.0  # flat: no peak, no NaN
    assert parabolic_offset(1.0, 0.0, 1.0) == 0.0  # a valley
    n = TABLE_I.n_loops
    res = TABLE_I.doppler_resolution_mps
    np.testing.assert_allclose(doppler_of_bin(np.array([0, 1, n - 1, n / 2]), TABLE_I),
                               [0, res, -res, -n / 2 * res])


def test_tdm_correction_removes_the_angle_bias_of_fast_targets():
    config = TABLE_I
    p = np.array([[1.0, 4.0]])
    v = np.array([[0.0, 4.0]])             # fast: the TDM phase is large
    cube = synthesize_cube(config, p, v, np.ones(1), rng=np.random.default_rng(0),
                           noise_std=0.0)
    (rng_m, omega, dop, snr), status = point_cloud_of_cube(cube, config)
    r = np.hypot(*p[0])
    vr = float(v[0] @ p[0] / r)
    truth = np.pi * p[0, 0] / r
    best = np.argmax(snr)
    assert status == Status.OK
    assert abs(omega[best] - truth) < 0.05
    assert abs(dop[best] - vr) < 0.5 * config.doppler_resolution_mps
    # Without the correction (Doppler 0), the azimuth array straddles two
    # transmitters and the estimate moves.
    spec, _ = range_doppler(cube, config)
    k = int(round(rng_m[best] / config.range_resolution_m)) - 0
    col = int(round(dop[best] / config.doppler_resolution_mps)) % config.n_loops
    snap = spec[k - 1:k + 2, col, :]
    snap = snap[np.argmax(np.sum(np.abs(snap) ** 2, axis=1))][None]
    wrong, _ = estimate_omega(snap, np.zeros(1), config)
    right, _ = estimate_omega(snap, np.array([dop[best]]), config)
    assert abs(right[0] - truth) < 0.05
    assert abs(wrong[0] - truth) > 0.2


# -------------------------------------------------------------------- CFAR
def test_os_cfar_alpha_matches_rohling_closed_form():
    n, k, pfa = 24, 18, 1e-4
    alpha = os_cfar_alpha(n, k, pfa, 1)
    closed = np.prod([(n - i) / (n - i + alpha) for i in range(k)])
    assert closed == pytest.approx(pfa, rel=1e-6)
    # More channels concentrate the noise: a smaller factor for the same pfa.
    assert os_cfar_alpha(n, k, pfa, 12) < alpha
    with pytest.raises(ConfigurationError, match="rank=30 must be in"):
        os_cfar_alpha(n, 30, pfa, 1)


@pytest.mark.parametrize("n_channels", [1, 4])
def test_os_cfar_false_alarm_rate_and_noise_scale_on_gamma_noise(n_channels):
    cfg = CfarConfig(guard_cells=(1, 1), train_cells=(3, 2), pfa=1e-2)
    rng = np.random.default_rng(n_channels)
    power = rng.gamma(n_channels, size=(400, 60))
    detected, z = os_cfar_2d(power, cfg, n_channels)
    n = power.size
    # Cells of a neighbourhood share training cells, so the count is not
    # binomial; allow 6 binomial sigmas around n * pfa.
    assert abs(detected.sum() - n * cfg.pfa) < 6 * np.sqrt(n * cfg.pfa)
    scale = os_cfar_noise_scale(cfg.n_train, cfg.rank, n_channels)
    assert np.mean(z) / n_channels == pytest.approx(scale, rel=0.02)


def test_os_cfar_cells_agrees_with_the_whole_map_filter():
    cfg = CfarConfig()
    rng = np.random.default_rng(5)
    power = rng.gamma(12, size=(100, 60)).astype(np.float32)
    power[50, 10] *= 20
    power[0, 0] *= 20          # corners exercise the reflect / wrap padding
    power[99, 59] *= 20
    det_full, z_full = os_cfar_2d(power, cfg, 12)
    rows, cols = np.meshgrid(np.arange(100), np.arange(60), indexing="ij")
    det_cells, z_cells = os_cfar_cells(power, rows.ravel(), cols.ravel(), cfg, 12)
    np.testing.assert_array_equal(z_cells.reshape(100, 60), z_full)
    np.testing.assert_array_equal(det_cells.reshape(100, 60), det_full)
    assert det_full[50, 10] and det_full[0, 0] and det_full[99, 59]
    with pytest.raises(ConfigurationError, match="cells outside"):
        os_cfar_cells(power, np.array([100]), np.array([0]), cfg)


def test_cfar_config_errors():
    with pytest.raises(ConfigurationError, match="guard_cells"):
        CfarConfig(guard_cells=(1,))
    with pytest.raises(ConfigurationError, match="train_cells"):
        CfarConfig(train_cells=(1.5, 2))
    with pytest.raises(ConfigurationError, match="leaves no training cells"):
        CfarConfig(train_cells=(0, 0))
    with pytest.raises(ConfigurationError, match="rank_fraction"):
        CfarConfig(rank_fraction=0.0)
    with pytest.raises(ConfigurationError, match="pfa"):
        CfarConfig(pfa=1.5)


# ------------------------------------------------------------ point clouds
@CONFIGS
def test_detections_within_one_resolution_cell(config):
    rng = np.random.default_rng(11)
    omega_res = 2 * np.pi / config.n_azimuth
    for trial in range(4):
        n = 3
        r = rng.uniform(2.0, 9.0, n)
        theta = rng.uniform(-0.8, 0.8, n)
        p = np.stack([r * np.sin(theta), r * np.cos(theta)], axis=1)
        v = rng.uniform(-1.5, 1.5, (n, 2))
        amp = scatterer_amplitude(config, 0.5, r) * np.exp(2j * np.pi * rng.random(n))
        cube = synthesize_cube(config, p, v, amp, rng=rng, noise_std=1.0)
        (det_r, det_w, det_v, snr), status = point_cloud_of_cube(cube, config)
        assert status == Status.OK
        assert np.all(np.isfinite(snr)) and np.all(snr > 0)
        vr = np.sum(v * p, axis=1) / r
        if np.any(np.abs(vr) < 1.5 * config.doppler_resolution_mps):
            continue  # in the clutter notch by design
        for i in range(n):
            # The detection nearest in (range, Doppler) cells.
            d = np.hypot((det_r - r[i]) / config.range_resolution_m,
                         (det_v - vr[i]) / config.doppler_resolution_mps)
            j = np.argmin(d)
            assert abs(det_r[j] - r[i]) <= config.range_resolution_m, (trial, i)
            assert abs(det_v[j] - vr[i]) <= config.doppler_resolution_mps, (trial, i)
            assert abs(det_w[j] - np.pi * np.sin(theta[i])) <= omega_res, (trial, i)


def test_cells_and_full_cfar_give_the_same_point_cloud():
    config = TABLE_I
    rng = np.random.default_rng(2)
    p = np.array([[1.0, 3.0], [-2.0, 6.0], [0.5, 8.0]])
    v = np.array([[0.0, 1.0], [0.5, -1.0], [-0.3, 0.7]])
    amp = scatterer_amplitude(config, 0.3, np.hypot(p[:, 0], p[:, 1]))
    cube = synthesize_cube(config, p, v, amp, rng=rng, noise_std=1.0)
    a, _ = point_cloud_of_cube(cube, config, ChainConfig(cfar_method="cells"))
    b, _ = point_cloud_of_cube(cube, config, ChainConfig(cfar_method="full"))
    assert len(a[0]) >= 3
    for x, y in zip(a, b):
        np.testing.assert_allclose(np.sort(x), np.sort(y))
    det, status = detect_frame(cube, config, frame=12)
    assert status == Status.OK and len(det) == len(a[0])
    assert np.all(det.frame == 12)
    np.testing.assert_array_equal(det.range_m, a[0])
    np.testing.assert_array_equal(det.snr_db, a[3])


def test_chain_false_alarm_rate_is_near_the_design_rate():
    # Noise-only Table I frames at pfa = 1e-3: the chain's detections are
    # false alarms. Windowing correlates neighbouring cells (more) and peak
    # grouping keeps one per local maximum (fewer); the net rate stays
    # within [0.7, 1.6] of pfa times the cells searched (measured: 1.27).
    config = TABLE_I
    chain = ChainConfig(cfar=CfarConfig(pfa=1e-3))
    rng = np.random.default_rng(8)
    count = 0
    n_frames = 5
    for _ in range(n_frames):
        noise = rng.standard_normal((*config.cube_shape[:2], 2 * config.n_virtual),
                                    dtype=np.float32).view(np.complex64)
        count += len(point_cloud_of_cube(noise, config, chain)[0][0])
    lo = int(np.ceil(chain.min_range_m / config.range_resolution_m))
    cells = (config.n_samples - lo) * (config.n_loops - 1)   # Doppler 0 is the notch
    design = n_frames * cells * 1e-3
    assert 0.7 * design < count < 1.6 * design


def test_static_clutter_is_removed():
    config = TABLE_I
    rng = np.random.default_rng(4)
    clutter = (np.array([[1.0, 2.0], [-3.0, 5.0], [2.0, 9.0]]), np.full(3, 30.0))
    mover_p, mover_v = np.array([[0.0, 4.0]]), np.array([[0.0, 1.0]])
    cube = synthesize_cube(config, mover_p, mover_v, np.array([0.2]), rng=rng, noise_std=1.0,
                           clutter=clutter)
    (r, w, v, s), _ = point_cloud_of_cube(cube, config)
    assert np.all(np.abs(v) > 0.5 * config.doppler_resolution_mps)
    assert np.any(np.abs(r - 4.0) < config.range_resolution_m)
    # Without clutter removal the walls are detected at zero Doppler.
    (r2, _, v2, _), _ = point_cloud_of_cube(cube, config, ChainConfig(clutter_removal=False))
    walls = np.hypot(clutter[0][:, 0], clutter[0][:, 1])
    for wall in walls:
        near = np.abs(r2 - wall) < config.range_resolution_m
        assert np.any(near & (np.abs(v2) < 0.5 * config.doppler_resolution_mps)), wall


def test_degenerate_frames_give_no_detections_and_no_nan():
    config = TABLE_I
    shape = config.cube_shape
    rng = np.random.default_rng(0)
    cases = {
        "empty_noise": (rng.standard_normal(shape) + 1j * rng.standard_normal(shape)),
        "all_zero": np.zeros(shape, np.complex64),
        "saturated_constant": np.full(shape, 32767 + 32767j, np.complex64),
        "nan": np.full(shape, np.nan, np.complex64),
    }
    want = {"empty_noise": Status.OK, "all_zero": Status.ALL_ZERO_CUBE,
            "saturated_constant": Status.OK, "nan": Status.NON_FINITE_SAMPLES}
    for name, cube in cases.items():
        cols, status = point_cloud_of_cube(cube, config)
        assert status == want[name], name
        assert all(c.size == 0 for c in cols), name
    # A saturated, clipped frame with the ADC full scale known is flagged.
    clipped = (np.sign(rng.standard_normal(shape)) * 32767
               + 1j * np.sign(rng.standard_normal(shape)) * 32767).astype(np.complex64)
    cols, status = point_cloud_of_cube(clipped, config, ChainConfig(adc_full_scale=32767))
    assert status == Status.SATURATED and cols[0].size == 0
    # A sequence with bad frames goes on and says so.
    cubes = np.stack([cases["all_zero"], cases["nan"], cases["empty_noise"]]).astype(np.complex64)
    res = process_cubes(cubes, config, frames=np.array([7, 8, 9]))
    assert not res.success
    assert "2 of 3 frames" in res.message and "frame 7" in res.message
    np.testing.assert_array_equal(res.status, [Status.ALL_ZERO_CUBE, Status.NON_FINITE_SAMPLES,
                                               Status.OK])
    assert np.all(np.isfinite(res.point_cloud.measurements))


def test_cube_shape_mismatch_is_a_configuration_error():
    cube = np.zeros((256, 60, 12), np.complex64)
    with pytest.raises(ConfigurationError, match=r"cube shape \(256, 60, 12\) disagrees .*"
                                                 r"n_samples=512"):
        point_cloud_of_cube(cube, TABLE_I)
    with pytest.raises(ConfigurationError, match=r"expected \(F, 512, 60, 12\)"):
        process_cubes(cube[None], TABLE_I)
    with pytest.raises(ConfigurationError, match=r"expected \(F, 512, 60, 12\)"):
        check_cube(cube[None], TABLE_I, frames=True)
    with pytest.raises(ConfigurationError, match="cube must be numeric"):
        check_cube(np.full(TABLE_I.cube_shape, "a"), TABLE_I)
    with pytest.raises(ConfigurationError, match="config must be a RadarConfig"):
        process_cubes(cube[None], {"n_samples": 256})
    with pytest.raises(ValidationError, match="frames is required"):
        process_cubes(iter([cube]), SMALL_RADAR)
    with pytest.raises(ValidationError, match=r"frames must be \(1,\) int"):
        process_cubes(np.zeros((1, *SMALL_RADAR.cube_shape), np.complex64), SMALL_RADAR,
                      frames=np.array([0.5]))


def test_chain_config_errors():
    with pytest.raises(ConfigurationError, match="not a scipy.signal window"):
        ChainConfig(range_window="nonsense")
    with pytest.raises(ConfigurationError, match="angle_fft_size"):
        ChainConfig(angle_fft_size=4)
    with pytest.raises(ConfigurationError, match="min_range_m"):
        ChainConfig(min_range_m=-1.0)
    with pytest.raises(ConfigurationError, match="max_range_m"):
        ChainConfig(min_range_m=2.0, max_range_m=1.0)
    with pytest.raises(ConfigurationError, match="cfar_method"):
        ChainConfig(cfar_method="fast")
    with pytest.raises(ConfigurationError, match="prescreen_db"):
        ChainConfig(prescreen_db=-1.0)
    with pytest.raises(ConfigurationError, match="dynamic_range_db"):
        ChainConfig(dynamic_range_db=0.0)
    with pytest.raises(ConfigurationError, match="adc_full_scale"):
        ChainConfig(adc_full_scale=0.0)
    with pytest.raises(ConfigurationError, match="max_saturated_fraction"):
        ChainConfig(max_saturated_fraction=2.0)
    with pytest.raises(ConfigurationError, match="keeps 1 range bins"):
        point_cloud_of_cube(np.ones(TABLE_I.cube_shape, np.complex64), TABLE_I,
                            ChainConfig(min_range_m=1.0, max_range_m=1.04))
    with pytest.raises(ConfigurationError, match="eps_m"):
        ClusterConfig(eps_m=0.0)
    with pytest.raises(ConfigurationError, match="min_samples"):
        ClusterConfig(min_samples=0)
    with pytest.raises(ConfigurationError, match="method"):
        ClusterConfig(method="median")


# --------------------------------------------------------------- clustering
def _walker_cubes(config, states, seed, *, bodies=1):
    from mmsnap_graph.sim.body import body_scatterers

    rng = np.random.default_rng(seed)
    pos, vel, amp = [], [], []
    for st in states:
        b = body_scatterers(st, config.frame_period_s, rng=rng)
        r = np.hypot(b.positions_m[..., 0], b.positions_m[..., 1])
        a = scatterer_amplitude(config, b.rcs_m2[None, :], r)
        pos.append(b.positions_m)
        vel.append(b.velocities_mps)
        amp.append(a * np.exp(2j * np.pi * rng.random(a.shape)))
    pos, vel, amp = (np.concatenate(x, axis=1) for x in (pos, vel, amp))
    return synthesize_cubes(config, pos, vel, amp, rng=rng, noise_std=1.0)


@pytest.mark.slow
def test_torso_centroid_beats_the_cluster_mean_when_limbs_swing():
    # A person walking toward the radar: arms and legs swing along the line
    # of sight, so their micro-Doppler and range offsets are largest.
    config = TABLE_I
    n = 24
    t = np.arange(n) * config.frame_period_s
    st = np.stack([0.5 + 0 * t, 8.5 - 1.2 * t, 0 * t, np.full(n, -1.2)], axis=1)
    res = process_cubes(_walker_cubes(config, [st], seed=3), config)
    torso = res.centroids
    mean = torso_centroids(res.point_cloud, ClusterConfig(method="mean"),
                           doppler_resolution_mps=config.doppler_resolution_mps)
    assert len(torso) >= n - 2 and len(mean) == len(torso)

    def rmse(cen):
        s = st[cen.frame]
        r = np.hypot(s[:, 0], s[:, 1])
        vr = np.sum(s[:, :2] * s[:, 2:], axis=1) / r
        return (np.sqrt(np.mean((cen.range_m - r) ** 2)),
                np.sqrt(np.mean((cen.doppler_mps - vr) ** 2)))

    (tr, tv), (mr, mv) = rmse(torso), rmse(mean)
    # The limbs' micro-Doppler pulls the mean; the torso mode is immune.
    assert tv < 0.5 * mv
    assert tv < 0.5 * config.doppler_resolution_mps
    # Range: both within about a resolution cell (the limbs swing
    # symmetrically about the hips, so the mean is not biased in range).
    assert tr < 2 * config.range_resolution_m
    assert tr < mr + config.range_resolution_m
    # Overall, in resolution cells, the torso centroid is closer.
    cells = lambda r, v: np.hypot(r / config.range_resolution_m, v / config.doppler_resolution_mps)
    assert cells(tr, tv) < cells(mr, mv)


def test_two_people_give_two_centroids():
    config = TABLE_I
    n = 4
    t = np.arange(n) * config.frame_period_s
    a = np.stack([-1.5 + 0 * t, 4.0 + 1.0 * t, 0 * t, np.full(n, 1.0)], axis=1)
    b = np.stack([2.0 + 0 * t, 8.0 - 1.0 * t, 0 * t, np.full(n, -1.0)], axis=1)
    res = process_cubes(_walker_cubes(config, [a, b], seed=4), config)
    for f in range(n):
        rows = res.centroids.frame == f
        assert rows.sum() == 2, f
        got = np.sort(res.centroids.range_m[rows])
        want = np.sort([np.hypot(*a[f, :2]), np.hypot(*b[f, :2])])
        np.testing.assert_allclose(got, want, atol=0.15)


def test_cluster_labels_and_edge_cases():
    cfg = ClusterConfig(min_samples=3)
    # Fewer points than min_samples: all noise, no centroid.
    assert np.all(cluster_labels(np.array([5.0, 5.1]), np.zeros(2), cfg) == -1)
    det = Detections(frame=[0, 0], range_m=[5.0, 5.1], omega_rad=[0.0, 0.0],
                     doppler_mps=[1.0, 1.0], snr_db=[10.0, 10.0])
    assert len(torso_centroids(det, cfg, doppler_resolution_mps=0.18)) == 0
    assert len(torso_centroids(Detections.empty(), cfg, doppler_resolution_mps=0.18)) == 0
    # Two tight groups 3 m apart in range: two clusters.
    r = np.array([4.0, 4.05, 4.1, 7.0, 7.05, 7.1])
    labels = cluster_labels(r, np.zeros(6), cfg)
    assert len(set(labels)) == 2 and labels[0] != labels[3]
    # The torso mode ignores one strong outlier in Doppler.
    det = Detections(frame=np.zeros(5, int), range_m=[5.0, 5.02, 5.04, 5.06, 5.3],
                     omega_rad=np.zeros(5), doppler_mps=[1.0, 1.01, 0.99, 1.0, 3.0],
                     snr_db=[12.0, 12.0, 12.0, 12.0, 30.0])
    cen = torso_centroids(det, cfg, doppler_resolution_mps=0.18)
    assert len(cen) == 1 and cen.doppler_mps[0] == pytest.approx(1.0, abs=0.01)
    assert cen.range_m[0] == pytest.approx(5.03, abs=0.01)
    assert cen.target_id[0] == -1


def test_cells_chain_matches_the_whole_map_cfar_on_a_32_loop_cube():
    config = dataclasses.replace(TABLE_I, n_loops=32)
    rng = np.random.default_rng(6)
    p = np.array([[1.0, 3.0], [-2.0, 6.0], [0.5, 8.0], [2.5, 4.5]])
    v = np.array([[0.0, 1.0], [0.5, -1.0], [-0.3, 0.7], [0.2, -2.0]])
    amp = scatterer_amplitude(config, 0.3, np.hypot(p[:, 0], p[:, 1]))
    cube = synthesize_cube(config, p, v, amp, rng=rng, noise_std=1.0)
    a, _ = point_cloud_of_cube(cube, config, ChainConfig(cfar_method="cells"))
    b, _ = point_cloud_of_cube(cube, config, ChainConfig(cfar_method="full"))
    assert len(a[0]) >= 4
    for x, y in zip(a, b):
        np.testing.assert_array_equal(np.sort(x), np.sort(y))


@pytest.mark.parametrize("cfar", [CfarConfig(guard_cells=(0, 1), train_cells=(0, 3)),
                                  CfarConfig(guard_cells=(2, 0), train_cells=(8, 0))])
def test_cells_chain_with_a_one_axis_footprint_matches_the_whole_map_cfar(cfar):
    # Half-size 0 on one axis: the local-maximum test pads that axis itself.
    config = dataclasses.replace(TABLE_I, n_loops=32)
    rng = np.random.default_rng(9)
    p = np.array([[1.0, 3.0], [-2.0, 6.0], [0.5, 8.0]])
    v = np.array([[0.0, 1.0], [0.5, -1.0], [-0.3, 0.7]])
    amp = scatterer_amplitude(config, 0.3, np.hypot(p[:, 0], p[:, 1]))
    cube = synthesize_cube(config, p, v, amp, rng=rng, noise_std=1.0)
    a, _ = point_cloud_of_cube(cube, config, ChainConfig(cfar=cfar, cfar_method="cells"))
    b, _ = point_cloud_of_cube(cube, config, ChainConfig(cfar=cfar, cfar_method="full"))
    assert len(a[0]) >= 3
    for x, y in zip(a, b):
        np.testing.assert_array_equal(np.sort(x), np.sort(y))


# TDM-MIMO Doppler de-aliasing: a target faster than the unambiguous speed keeps
# its Doppler, its angle and its heading through the chain and the EKF.


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


# Point targets and near-field leakage.


def _reflector_cubes(n=12, seed=2, extra=None):
    """A corner reflector (10 m^2) walked slowly away at 6 m, 20 degrees off broadside;
    ``extra``: more scatterers ``(position (2,), velocity (2,), rcs)`` per frame."""
    rng = np.random.default_rng(seed)
    u = np.array([np.sin(0.35), np.cos(0.35)])
    pos, vel, amp = [], [], []
    for f in range(n):
        p = [(6.0 + 0.5 * f * TABLE_I.frame_period_s) * u]
        v = [0.5 * u]
        rcs = [10.0]
        for q, w, s in (extra or []):
            p.append(np.asarray(q, float))
            v.append(np.asarray(w, float))
            rcs.append(s)
        p = np.array(p)
        pos.append(p)
        vel.append(np.array(v))
        amp.append(scatterer_amplitude(TABLE_I, np.array(rcs), np.hypot(p[:, 0], p[:, 1])))
    return synthesize_cubes(TABLE_I, pos, vel, amp, rng=rng), u


def test_isolated_reflector_is_a_centroid_in_point_target_mode():
    cubes, u = _reflector_cubes()
    people = process_cubes(cubes, TABLE_I)
    points = process_cubes(cubes, TABLE_I, ChainConfig(cluster=ClusterConfig(point_targets=True)))
    # DBSCAN's three-point minimum drops the lone peak (issue 14: 32 of 101 frames) ...
    assert len(people.centroids) < len(cubes) // 2
    # ... the point-target mode gives it a centroid in every frame.
    assert np.unique(points.centroids.frame).size == len(cubes)
    t = np.arange(len(cubes)) * TABLE_I.frame_period_s
    first = np.array([np.flatnonzero(points.centroids.frame == f)[0] for f in range(len(cubes))])
    np.testing.assert_allclose(points.centroids.range_m[first], 6.0 + 0.5 * t, atol=0.03)
    np.testing.assert_allclose(points.centroids.omega_rad[first], np.pi * u[0], atol=0.05)
    np.testing.assert_allclose(points.centroids.doppler_mps[first], 0.5, atol=0.05)


def test_default_min_range_clears_near_field_residue():
    """A near-field residue (leakage through the radome that moves with the
    radar's own vibration, so clutter removal leaves it) at 0.72-0.78 m."""
    residue = [((0.02, 0.75), (0.0, 0.15), 1.0), ((-0.03, 0.72), (0.0, -0.1), 1.0)]
    cubes, _ = _reflector_cubes(n=8, seed=5, extra=residue)
    cfg = ClusterConfig(point_targets=True)
    old = process_cubes(cubes, TABLE_I, ChainConfig(min_range_m=0.3, cluster=cfg))
    new = process_cubes(cubes, TABLE_I, ChainConfig(cluster=cfg))
    assert DEFAULT_MIN_RANGE_M == ChainConfig().min_range_m == 0.9
    near_old = old.centroids.range_m < 0.85
    assert np.unique(old.centroids.frame[near_old]).size == len(cubes)  # false centroids
    assert new.point_cloud.range_m.min() >= 0.9 - TABLE_I.range_resolution_m
    assert np.all(new.centroids.range_m > 5.0)
    assert np.unique(new.centroids.frame).size == len(cubes)


@pytest.mark.parametrize("value", [np.inf, 1e308, 1e5])
def test_a_max_range_beyond_the_chains_is_refused(value):
    """Before: max_range_m=inf (or 1e308) was accepted and the range bins'
    int(floor(max_range_m / resolution)) raised OverflowError in
    point_cloud_of_cube (`mmsnap process` with `[chain] max_range_m = inf`)."""
    from mmsnap_graph.errors import ConfigurationError
    from mmsnap_graph.radar.chain import ChainConfig

    with pytest.raises(ConfigurationError, match=r"max_range_m=.* at most 10000"):
        ChainConfig(max_range_m=value)
    assert ChainConfig(max_range_m=1e4).max_range_m == 1e4
