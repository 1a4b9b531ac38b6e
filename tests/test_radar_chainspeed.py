"""The faster chain (issue 14, item 8) computes the same numbers: the
screened OS-CFAR, the slice-filled padding, the one-batch angle estimation
and the all-frames clustering agree with their references."""

import dataclasses

import numpy as np
import pytest

from mmsnap_graph.data.radar_config import TABLE_I
from mmsnap_graph.data.recording import Detections
from mmsnap_graph.radar.cfar import CfarConfig, os_cfar_cells, os_cfar_detections, pad_map
from mmsnap_graph.radar.chain import ChainConfig, point_cloud_of_cube
from mmsnap_graph.radar.cluster import ClusterConfig, torso_centroids
from mmsnap_graph.radar.spectrum import estimate_omega, estimate_omega_dealiased
from mmsnap_graph.sim.cube import scatterer_amplitude, synthesize_cube


@pytest.mark.parametrize("cfg", [
    CfarConfig(),
    CfarConfig(rank_fraction=0.5, pfa=1e-3),
    CfarConfig(rank_fraction=1.0, pfa=1e-2),
    CfarConfig(guard_cells=(0, 0), train_cells=(1, 1), rank_fraction=0.9),
    CfarConfig(guard_cells=(1, 2), train_cells=(3, 0)),
])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_os_cfar_detections_are_the_detected_cells_of_os_cfar_cells(cfg, dtype):
    rng = np.random.default_rng(3)
    power = rng.gamma(12, size=(60, 32)).astype(dtype)
    hot = rng.integers(0, power.size, 40)
    power.ravel()[hot] *= rng.uniform(1, 30, hot.size)  # some pass, some fail
    rows, cols = np.nonzero(np.ones(power.shape, bool))
    det, z = os_cfar_cells(power, rows, cols, cfg, 12)
    keep, z_keep = os_cfar_detections(power, rows, cols, cfg, 12)
    assert det.sum() > 0 and det.sum() < det.size
    np.testing.assert_array_equal(keep, np.flatnonzero(det))
    np.testing.assert_array_equal(z_keep, z[det])
    keep2, z2 = os_cfar_detections(power, rows, cols, cfg, 12, padded=pad_map(power, cfg))
    np.testing.assert_array_equal(keep2, keep)
    np.testing.assert_array_equal(z2, z_keep)
    empty = os_cfar_detections(power, rows[:0], cols[:0], cfg, 12)
    assert empty[0].shape == (0,) and empty[1].shape == (0,)


@pytest.mark.parametrize("shape", [(1, 1), (3, 2), (5, 9), (21, 9), (40, 16), (486, 32)])
def test_pad_map_equals_numpy_pad(shape):
    cfg = CfarConfig()
    power = np.random.default_rng(1).random(shape).astype(np.float32)
    hr, hd = 10, 4
    want = np.pad(np.pad(power, ((0, 0), (hd, hd)), mode="wrap"), ((hr, hr), (0, 0)),
                  mode="symmetric")
    got = pad_map(power, cfg)
    assert got.dtype == want.dtype
    np.testing.assert_array_equal(got, want)


def test_dealias_mask_gives_the_plain_estimate_where_off():
    config = TABLE_I
    rng = np.random.default_rng(4)
    snap = (rng.standard_normal((9, config.n_virtual))
            + 1j * rng.standard_normal((9, config.n_virtual))).astype(np.complex64)
    v = rng.uniform(-config.max_doppler_mps, config.max_doppler_mps, 9)
    mask = np.array([True, False, True, True, False, False, True, False, True])
    om, share, dop = estimate_omega_dealiased(snap, v, config, dealias=mask)
    om_all, share_all, dop_all = estimate_omega_dealiased(snap, v, config)
    om_plain, share_plain = estimate_omega(snap, v, config)
    np.testing.assert_array_equal(om[mask], om_all[mask])
    np.testing.assert_array_equal(dop[mask], dop_all[mask])
    np.testing.assert_array_equal(om[~mask], om_plain[~mask])
    # the share's float32 sum of 64 bins may differ in its last bit between the
    # batched and the plain FFT layout (the chain does not use it)
    np.testing.assert_allclose(share[~mask], share_plain[~mask], rtol=1e-6)
    np.testing.assert_array_equal(dop[~mask], v[~mask])
    om0, _, dop0 = estimate_omega_dealiased(snap, v, config, dealias=np.zeros(9, bool))
    np.testing.assert_array_equal(om0, om_plain)
    np.testing.assert_array_equal(dop0, v)
    with pytest.raises(Exception, match="dealias"):
        estimate_omega_dealiased(snap, v, config, dealias=mask[:3])


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


@pytest.mark.parametrize("cluster", [ClusterConfig(), ClusterConfig(point_targets=True),
                                     ClusterConfig(method="mean", min_samples=2)])
@pytest.mark.parametrize("with_snr", [True, False])
def test_torso_centroids_of_many_frames_equal_frame_by_frame(cluster, with_snr):
    rng = np.random.default_rng(8)
    n_frames = 30
    sizes = rng.integers(0, 9, n_frames)
    frame = np.repeat(np.arange(n_frames) * 3 + 5, sizes)
    k = frame.size
    centre = rng.uniform(2, 8, n_frames).repeat(sizes)
    cloud = Detections(frame=frame,
                       range_m=centre + rng.normal(0, 0.2, k),
                       omega_rad=rng.normal(0.2, 0.15, k),
                       doppler_mps=rng.normal(1.0, 0.3, k),
                       snr_db=rng.uniform(5, 25, k) if with_snr else None)
    shuffled = rng.permutation(k)  # frames need not be sorted
    cloud = Detections(frame=cloud.frame[shuffled], range_m=cloud.range_m[shuffled],
                       omega_rad=cloud.omega_rad[shuffled],
                       doppler_mps=cloud.doppler_mps[shuffled],
                       snr_db=None if cloud.snr_db is None else cloud.snr_db[shuffled])
    res = 0.1
    together = torso_centroids(cloud, cluster, doppler_resolution_mps=res)
    parts = []
    for f in np.unique(cloud.frame):
        m = np.flatnonzero(cloud.frame == f)
        one = Detections(frame=cloud.frame[m], range_m=cloud.range_m[m],
                         omega_rad=cloud.omega_rad[m], doppler_mps=cloud.doppler_mps[m],
                         snr_db=None if cloud.snr_db is None else cloud.snr_db[m])
        parts.append(torso_centroids(one, cluster, doppler_resolution_mps=res))
    assert len(together) > 5
    for name in ("frame", "range_m", "omega_rad", "doppler_mps", "snr_db"):
        want = np.concatenate([getattr(d, name) for d in parts if len(d)])
        np.testing.assert_array_equal(getattr(together, name), want)


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
