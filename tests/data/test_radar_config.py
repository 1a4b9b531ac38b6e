"""Radar chirp and array configuration (mmsnap_graph.data.radar_config): the
derived quantities against the FMCW formulas worked by hand for the paper's
Table I, the consistency checks and the dict round trip."""

from __future__ import annotations

import numpy as np
import pytest

from mmsnap_graph.data.radar_config import TABLE_I, RadarConfig, TiProfile
from mmsnap_graph.errors import ConfigurationError

C = 299_792_458.0


def test_table_i_derived_quantities():
    """76 GHz, 83 MHz/us, 512 complex samples at 10 MHz, 60 us chirps, 3 TX
    x 4 RX, 60 loops: B = 83e12 * 51.2e-6 = 4.2496 GHz, dR = c / (2 B) =
    3.527 cm, R_max = fs c / (2 S) = 18.06 m, loop 180 us, v_max = lambda /
    (4 T_loop) = 5.48 m/s, dv = lambda / (2 N T_loop) = 0.183 m/s."""
    cfg = TABLE_I
    assert cfg.cube_shape == (512, 60, 12)
    assert cfg.bandwidth_hz == pytest.approx(83e12 * 512 / 10e6, rel=1e-12)
    assert cfg.range_resolution_m == pytest.approx(C / (2 * 4.2496e9), rel=1e-12)
    assert cfg.max_range_m == pytest.approx(10e6 * C / (2 * 83e12), rel=1e-12)
    lam = C / 76e9
    assert cfg.wavelength_m == pytest.approx(lam, rel=1e-12)
    assert cfg.loop_period_s == pytest.approx(180e-6, rel=1e-12)
    assert cfg.max_doppler_mps == pytest.approx(lam / (4 * 180e-6), rel=1e-12)
    assert cfg.doppler_resolution_mps == pytest.approx(lam / (2 * 60 * 180e-6), rel=1e-12)
    # TX at azimuth 0, 2, 4 (elevation 0, 1, 0) and RX at 0..3: the middle TX
    # is raised, so the azimuth array is the 8 channels of TX 0 and TX 2.
    assert cfg.n_azimuth == 8
    assert [cfg.virtual_azimuth_half_wl[c] for c in cfg.azimuth_channels] == list(range(8))
    assert cfg.omega_resolution_rad == pytest.approx(2 * np.pi / 8)


def test_band_centre_wavelength_and_real_adc():
    cfg = RadarConfig(wavelength_reference="band_centre", complex_adc=False)
    centre = 76e9 + 83e12 * 512 / (2 * 10e6)
    assert cfg.band_centre_hz == pytest.approx(centre, rel=1e-12)
    assert cfg.wavelength_m == pytest.approx(C / centre, rel=1e-12)
    assert cfg.max_range_m == pytest.approx(TABLE_I.max_range_m / 2, rel=1e-12)


@pytest.mark.parametrize("kwargs, match", [
    ({"carrier_hz": 0.0}, "carrier_hz"),
    ({"frame_period_s": float("nan")}, "frame_period_s"),
    ({"n_loops": 1}, "n_loops"),
    ({"n_loops": 1000}, "longer than frame_period_s"),
    ({"n_samples": 1024}, "longer than chirp_period_s"),
    ({"tx_elevation_half_wl": (0.0, 0.0)}, "tx_elevation_half_wl has 2"),
    ({"rx_azimuth_half_wl": (0.0, 2.0, 4.0, 6.0)}, "uniform lambda/2 array"),
])
def test_inconsistent_configurations_are_refused_naming_the_field(kwargs, match):
    with pytest.raises(ConfigurationError, match=match):
        RadarConfig(**kwargs)


def test_dict_round_trip_and_unknown_fields():
    cfg = RadarConfig(n_samples=256, n_loops=32, adc_start_s=2e-6, complex_adc=False)
    d = cfg.to_dict()
    assert d["adc_start_s"] == 2e-6 and d["complex_adc"] is False
    assert "wavelength_reference" not in d  # optional fields at their default are left out
    assert RadarConfig.from_dict(d) == cfg
    assert RadarConfig.from_dict(TABLE_I.to_dict()) == TABLE_I
    with pytest.raises(ConfigurationError, match="unknown radar configuration fields"):
        RadarConfig.from_dict({**d, "gain_db": 3})


_PROFILE = dict(start_freq_hz=77e9, idle_s=7e-6, adc_start_s=6e-6, ramp_end_s=60e-6,
                slope_hz_per_s=60e12, n_samples=256, sample_rate_hz=5e6, n_loops=32,
                frame_period_s=0.1)
_ANTENNAS = dict(tx_azimuth_half_wl=[0, 4], tx_elevation_half_wl=[0, 0],
                 rx_azimuth_half_wl=[0, 1, 2, 3])


def test_a_ti_profile_on_an_antenna_layout():
    cfg = RadarConfig.from_ti_profile(TiProfile(**_PROFILE, complex_adc=False), **_ANTENNAS)
    assert cfg.chirp_period_s == pytest.approx(67e-6)
    assert cfg.wavelength_reference == "band_centre" and cfg.complex_adc is False
    centre = 77e9 + 60e12 * (6e-6 + 256 / (2 * 5e6))
    assert cfg.wavelength_m == pytest.approx(299_792_458.0 / centre, rel=1e-12)
    with pytest.raises(ConfigurationError, match="profile must be a TiProfile, got dict"):
        RadarConfig.from_ti_profile(_PROFILE, **_ANTENNAS)


@pytest.mark.parametrize("change, match", [
    ({"n_samples": 512}, r"n_samples=512 .* s ends after ramp_end_s=6e-05"),
    ({"sample_rate_hz": 0.0}, "sample_rate_hz=0.0 must be > 0"),
    ({"idle_s": -1e-6}, "idle_s=-1e-06 must be a finite number >= 0"),
    ({"adc_start_s": float("nan")}, "adc_start_s=nan"),
    ({"n_samples": 256.0}, "n_samples=256.0 must be an integer"),
])
def test_a_ti_profile_is_checked_once(change, match):
    with pytest.raises(ConfigurationError, match=match):
        TiProfile(**{**_PROFILE, **change})
