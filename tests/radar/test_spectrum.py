"""Angle estimation (mmsnap_graph.radar.spectrum): the de-aliased estimate,
its wrap hypotheses and its per-cell mask."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mmsnap_graph.data.radar_config import TABLE_I
from mmsnap_graph.radar.spectrum import estimate_omega, estimate_omega_dealiased, wrap_hypotheses


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
