"""Radar chirp and array configuration, as data (paper Table I by default).

The radar cube of one frame is a complex array of shape
``(n_samples, n_loops, n_tx * n_rx)``: fast-time ADC samples, slow-time chirp
loops, and virtual channels ordered ``tx_index * n_rx + rx_index`` in the
order the transmitters fire within a loop (TDM-MIMO). A recording stacks
frames in front: ``(F, n_samples, n_loops, n_virtual)``.

Antenna positions are given in units of half a wavelength. The default is the
AWR2243 boost-board layout: Tx0 and Tx2 two wavelengths apart in azimuth, Tx1
between them raised half a wavelength in elevation, four receivers half a
wavelength apart, giving an 8-element azimuth virtual array (Tx0, Tx2) with
spatial-frequency resolution ``2 pi / 8``.

Optional TI terms (all default to the behaviour above): ``adc_start_s`` (the
ADC starts sampling this long after the ramp starts), ``complex_adc``,
``rx_elevation_half_wl`` (2-D receiver layouts such as the IWR6843AOP),
``tx_channels`` (the physical transmitter of each chirp of a loop, for the
record) and ``wavelength_reference="band_centre"``, which makes
``wavelength_m`` the wavelength at the centre of the sampled band instead of
at ``carrier_hz`` (docs/TI.md). :meth:`RadarConfig.from_ti_profile` builds a
configuration from a TI profile's own terms.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from .._validation import check_count
from ..errors import ConfigurationError

__all__ = ["SPEED_OF_LIGHT_MPS", "WAVELENGTH_REFERENCES", "OPTIONAL_FIELD_DEFAULTS", "RadarConfig",
           "TiProfile", "TABLE_I"]

#: Where ``RadarConfig.wavelength_m`` is taken: the chirp's start frequency
#: (the paper's convention, the default) or the centre of the sampled band.
WAVELENGTH_REFERENCES = ("start", "band_centre")

# Fields added for TI configurations, with the defaults that keep the original
# behaviour; ``to_dict`` writes them only when they differ from these.
OPTIONAL_FIELD_DEFAULTS: dict[str, Any] = {
    "adc_start_s": 0.0,
    "complex_adc": True,
    "rx_elevation_half_wl": [],
    "tx_channels": [],
    "wavelength_reference": "start",
}

SPEED_OF_LIGHT_MPS = 299_792_458.0


def _tuple(x) -> tuple:
    return tuple(float(v) for v in x)


@dataclass(frozen=True, kw_only=True)
class TiProfile:
    """One chirp profile and frame in TI's terms (frozen; checked once).

    From ``profileCfg``: ``start_freq_hz``, ``idle_s``, ``adc_start_s``,
    ``ramp_end_s``, ``slope_hz_per_s``, ``n_samples``, ``sample_rate_hz``;
    from ``frameCfg``: ``n_loops``, ``frame_period_s``; from ``adcCfg`` /
    ``adcbufCfg``: ``complex_adc``. SI units (the ``.cfg`` file's GHz, us,
    MHz/us and ksps converted). The sampled band must end before the ramp:
    ``adc_start_s + n_samples / sample_rate_hz <= ramp_end_s``.
    :meth:`RadarConfig.from_ti_profile` puts it on an antenna layout.
    """

    start_freq_hz: float
    idle_s: float
    adc_start_s: float
    ramp_end_s: float
    slope_hz_per_s: float
    n_samples: int
    sample_rate_hz: float
    n_loops: int
    frame_period_s: float
    complex_adc: bool = True

    def __post_init__(self) -> None:
        for name in ("idle_s", "adc_start_s", "ramp_end_s", "sample_rate_hz"):
            v = getattr(self, name)
            if isinstance(v, (bool, np.bool_)) or not isinstance(
                    v, (int, float, np.integer, np.floating)) or not np.isfinite(v) or v < 0:
                raise ConfigurationError(f"{name}={v!r} must be a finite number >= 0")
        if not self.sample_rate_hz > 0:
            raise ConfigurationError(f"sample_rate_hz={self.sample_rate_hz!r} must be > 0")
        check_count(self.n_samples, "n_samples", error=ConfigurationError)
        sampled_s = self.adc_start_s + self.n_samples / self.sample_rate_hz
        if sampled_s > self.ramp_end_s * (1 + 1e-9):
            raise ConfigurationError(
                f"adc_start_s={self.adc_start_s!r} + n_samples={self.n_samples} / "
                f"sample_rate_hz={self.sample_rate_hz!r} = {sampled_s!r} s ends after "
                f"ramp_end_s={self.ramp_end_s!r}")


@dataclass(frozen=True, kw_only=True, slots=True)
class RadarConfig:
    """FMCW TDM-MIMO chirp and antenna configuration (SI units throughout).

    carrier_hz : start frequency of the chirp.
    sample_rate_hz : complex ADC sampling rate.
    n_samples : ADC samples per chirp.
    slope_hz_per_s : chirp slope.
    chirp_period_s : time from one chirp's start to the next (ramp + idle).
    n_loops : chirp loops per frame (each loop fires every transmitter once).
    frame_period_s : time between frames.
    tx_azimuth_half_wl, tx_elevation_half_wl : (n_tx,) transmitter positions.
    rx_azimuth_half_wl : (n_rx,) receiver positions.
    adc_start_s : ADC start time after the ramp start (TI ``adcStartTime``).
    complex_adc : complex (I/Q) ADC samples; False = real ADC.
    rx_elevation_half_wl : (n_rx,) receiver elevations, or () for all 0.
    tx_channels : (n_tx,) physical transmitter index of each chirp of a loop
        (TI ``TXn``), or () when unknown; informational.
    wavelength_reference : ``"start"`` (wavelength at ``carrier_hz``) or
        ``"band_centre"`` (at :attr:`band_centre_hz`).
    """

    carrier_hz: float = 76e9
    sample_rate_hz: float = 10e6
    n_samples: int = 512
    slope_hz_per_s: float = 83e12
    chirp_period_s: float = 60e-6
    n_loops: int = 60
    frame_period_s: float = 0.150
    tx_azimuth_half_wl: tuple = (0.0, 2.0, 4.0)
    tx_elevation_half_wl: tuple = (0.0, 1.0, 0.0)
    rx_azimuth_half_wl: tuple = (0.0, 1.0, 2.0, 3.0)
    adc_start_s: float = 0.0
    complex_adc: bool = True
    rx_elevation_half_wl: tuple = ()
    tx_channels: tuple = ()
    wavelength_reference: Literal["start", "band_centre"] = "start"
    _azimuth_channels: tuple = field(init=False, repr=False, compare=False, default=())

    def __post_init__(self) -> None:
        object.__setattr__(self, "tx_azimuth_half_wl", _tuple(self.tx_azimuth_half_wl))
        object.__setattr__(self, "tx_elevation_half_wl", _tuple(self.tx_elevation_half_wl))
        object.__setattr__(self, "rx_azimuth_half_wl", _tuple(self.rx_azimuth_half_wl))
        self._check_ti_fields()
        for name in ("carrier_hz", "sample_rate_hz", "slope_hz_per_s", "chirp_period_s",
                     "frame_period_s"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ConfigurationError(f"{name}={value!r} must be finite and > 0")
        for name in ("n_samples", "n_loops"):
            check_count(getattr(self, name), name, 2, error=ConfigurationError)
        if len(self.tx_azimuth_half_wl) != len(self.tx_elevation_half_wl):
            raise ConfigurationError(
                f"tx_azimuth_half_wl has {len(self.tx_azimuth_half_wl)} entries but "
                f"tx_elevation_half_wl has {len(self.tx_elevation_half_wl)}"
            )
        if not self.tx_azimuth_half_wl or not self.rx_azimuth_half_wl:
            raise ConfigurationError("at least one transmitter and one receiver are needed")
        if self.n_tx * self.chirp_period_s * self.n_loops > self.frame_period_s:
            raise ConfigurationError(
                f"the chirps of a frame last {self.n_tx * self.chirp_period_s * self.n_loops!r} s, "
                f"longer than frame_period_s={self.frame_period_s!r}"
            )
        if self.adc_start_s + self.n_samples / self.sample_rate_hz > self.chirp_period_s:
            start = f" after adc_start_s={self.adc_start_s!r}" if self.adc_start_s else ""
            raise ConfigurationError(
                f"sampling {self.n_samples} samples at {self.sample_rate_hz} Hz{start} takes "
                f"longer than chirp_period_s={self.chirp_period_s!r}"
            )
        # Azimuth array: the virtual channels at elevation 0 on the
        # lambda/2 grid, sorted by position; it must be uniform.
        pos = self.virtual_azimuth_half_wl
        elev = self.virtual_elevation_half_wl
        chans = [int(i) for i in np.argsort(pos, kind="stable") if elev[i] == 0.0]
        # Keep one channel per position (overlapping virtual elements).
        seen: dict[float, int] = {}
        for c in chans:
            seen.setdefault(pos[c], c)
        chans = [seen[p] for p in sorted(seen)]
        steps = np.diff([pos[c] for c in chans])
        if len(chans) < 2 or not np.allclose(steps, 1.0):
            raise ConfigurationError(
                "the azimuth virtual array must be a uniform lambda/2 array of >= 2 elements, "
                f"got positions {[pos[c] for c in chans]}"
            )
        object.__setattr__(self, "_azimuth_channels", tuple(chans))

    def _check_ti_fields(self) -> None:
        start = float(self.adc_start_s)
        if not (np.isfinite(start) and start >= 0):
            raise ConfigurationError(f"adc_start_s={self.adc_start_s!r} must be finite and >= 0")
        object.__setattr__(self, "adc_start_s", start)
        if not isinstance(self.complex_adc, (bool, np.bool_)):
            raise ConfigurationError(f"complex_adc={self.complex_adc!r} must be True or False")
        object.__setattr__(self, "complex_adc", bool(self.complex_adc))
        rx_el = _tuple(self.rx_elevation_half_wl)
        if rx_el and len(rx_el) != len(self.rx_azimuth_half_wl):
            raise ConfigurationError(
                f"rx_elevation_half_wl has {len(rx_el)} entries but rx_azimuth_half_wl has "
                f"{len(self.rx_azimuth_half_wl)}")
        object.__setattr__(self, "rx_elevation_half_wl", rx_el)
        tx_ch = tuple(int(v) for v in self.tx_channels)
        if tx_ch and len(tx_ch) != len(self.tx_azimuth_half_wl):
            raise ConfigurationError(
                f"tx_channels={tx_ch!r} must name one transmitter per entry of "
                f"tx_azimuth_half_wl ({len(self.tx_azimuth_half_wl)})")
        object.__setattr__(self, "tx_channels", tx_ch)
        if self.wavelength_reference not in WAVELENGTH_REFERENCES:
            raise ConfigurationError(f"wavelength_reference={self.wavelength_reference!r} must "
                                     f"be one of {WAVELENGTH_REFERENCES}")

    @classmethod
    def from_ti_profile(cls, profile: TiProfile, *, tx_azimuth_half_wl, tx_elevation_half_wl,
                        rx_azimuth_half_wl, rx_elevation_half_wl=(),
                        tx_channels=()) -> "RadarConfig":
        """A configuration in TI's terms: the chirp and frame of ``profile``
        (:class:`TiProfile`, ``profileCfg`` / ``frameCfg`` / ``adcCfg``) on
        the antennas given here. The chirp period is ``idle_s + ramp_end_s``
        and the wavelength is taken at the centre of the sampled band
        (docs/TI.md)."""
        if not isinstance(profile, TiProfile):
            raise ConfigurationError(f"profile must be a TiProfile, got {type(profile).__name__}")
        p = profile
        return cls(carrier_hz=p.start_freq_hz, sample_rate_hz=p.sample_rate_hz,
                   n_samples=int(p.n_samples), slope_hz_per_s=p.slope_hz_per_s,
                   chirp_period_s=p.idle_s + p.ramp_end_s, n_loops=int(p.n_loops),
                   frame_period_s=p.frame_period_s, tx_azimuth_half_wl=tx_azimuth_half_wl,
                   tx_elevation_half_wl=tx_elevation_half_wl,
                   rx_azimuth_half_wl=rx_azimuth_half_wl,
                   rx_elevation_half_wl=rx_elevation_half_wl, tx_channels=tx_channels,
                   adc_start_s=p.adc_start_s, complex_adc=p.complex_adc,
                   wavelength_reference="band_centre")

    # ---- sizes -------------------------------------------------------------
    @property
    def n_tx(self) -> int:
        return len(self.tx_azimuth_half_wl)

    @property
    def n_rx(self) -> int:
        return len(self.rx_azimuth_half_wl)

    @property
    def n_virtual(self) -> int:
        return self.n_tx * self.n_rx

    @property
    def cube_shape(self) -> tuple[int, int, int]:
        """Shape of one frame's cube: ``(n_samples, n_loops, n_virtual)``."""
        return (int(self.n_samples), int(self.n_loops), self.n_virtual)

    @property
    def virtual_azimuth_half_wl(self) -> np.ndarray:
        """(n_virtual,) azimuth position of each virtual channel, ``tx * n_rx + rx``."""
        return (np.asarray(self.tx_azimuth_half_wl)[:, None]
                + np.asarray(self.rx_azimuth_half_wl)[None, :]).ravel()

    @property
    def virtual_elevation_half_wl(self) -> np.ndarray:
        """(n_virtual,) elevation of each virtual channel, ``tx * n_rx + rx``."""
        rx_el = (np.asarray(self.rx_elevation_half_wl) if self.rx_elevation_half_wl
                 else np.zeros(self.n_rx))
        return (np.asarray(self.tx_elevation_half_wl)[:, None] + rx_el[None, :]).ravel()

    @property
    def azimuth_channels(self) -> tuple[int, ...]:
        """Virtual channel indices of the uniform azimuth array, in position order."""
        return self._azimuth_channels

    @property
    def n_azimuth(self) -> int:
        return len(self._azimuth_channels)

    # ---- derived physics ---------------------------------------------------
    @property
    def band_centre_hz(self) -> float:
        """Frequency at the centre of the sampled band,
        ``carrier + slope (adc_start + n_samples / (2 fs))``."""
        return self.carrier_hz + self.slope_hz_per_s * (
            self.adc_start_s + self.n_samples / (2.0 * self.sample_rate_hz))

    @property
    def wavelength_m(self) -> float:
        """Wavelength for Doppler and angle: at ``carrier_hz`` by default, at
        :attr:`band_centre_hz` with ``wavelength_reference="band_centre"``."""
        if self.wavelength_reference == "band_centre":
            return SPEED_OF_LIGHT_MPS / self.band_centre_hz
        return SPEED_OF_LIGHT_MPS / self.carrier_hz

    @property
    def bandwidth_hz(self) -> float:
        """Sampled bandwidth ``slope * n_samples / fs``."""
        return self.slope_hz_per_s * self.n_samples / self.sample_rate_hz

    @property
    def range_resolution_m(self) -> float:
        return SPEED_OF_LIGHT_MPS / (2.0 * self.bandwidth_hz)

    @property
    def max_range_m(self) -> float:
        """Complex ADC: beat frequencies up to ``fs`` map to ``fs c / (2 slope)``;
        a real ADC reaches half of that."""
        if not self.complex_adc:
            return self.sample_rate_hz * SPEED_OF_LIGHT_MPS / (4.0 * self.slope_hz_per_s)
        return self.sample_rate_hz * SPEED_OF_LIGHT_MPS / (2.0 * self.slope_hz_per_s)

    @property
    def loop_period_s(self) -> float:
        """Time between two chirps of the same transmitter."""
        return self.n_tx * self.chirp_period_s

    @property
    def doppler_resolution_mps(self) -> float:
        return self.wavelength_m / (2.0 * self.n_loops * self.loop_period_s)

    @property
    def max_doppler_mps(self) -> float:
        """Unambiguous radial velocity is ``[-max, max)``."""
        return self.wavelength_m / (4.0 * self.loop_period_s)

    @property
    def omega_resolution_rad(self) -> float:
        return 2.0 * np.pi / self.n_azimuth

    # ---- (de)serialization -------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """Plain-Python dict of the constructor fields (for HDF5 attributes, JSON)."""
        return {
            "carrier_hz": float(self.carrier_hz),
            "sample_rate_hz": float(self.sample_rate_hz),
            "n_samples": int(self.n_samples),
            "slope_hz_per_s": float(self.slope_hz_per_s),
            "chirp_period_s": float(self.chirp_period_s),
            "n_loops": int(self.n_loops),
            "frame_period_s": float(self.frame_period_s),
            "tx_azimuth_half_wl": list(self.tx_azimuth_half_wl),
            "tx_elevation_half_wl": list(self.tx_elevation_half_wl),
            "rx_azimuth_half_wl": list(self.rx_azimuth_half_wl),
        } | self._optional_dict()

    def _optional_dict(self) -> dict[str, Any]:
        values = {"adc_start_s": float(self.adc_start_s), "complex_adc": bool(self.complex_adc),
                  "rx_elevation_half_wl": list(self.rx_elevation_half_wl),
                  "tx_channels": list(self.tx_channels),
                  "wavelength_reference": str(self.wavelength_reference)}
        return {k: v for k, v in values.items() if v != OPTIONAL_FIELD_DEFAULTS[k]}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "RadarConfig":
        known = set(cls().to_dict()) | set(OPTIONAL_FIELD_DEFAULTS)
        unknown = set(d) - known
        if unknown:
            raise ConfigurationError(f"unknown radar configuration fields {sorted(unknown)}")
        kw = dict(d)
        for k in ("n_samples", "n_loops"):
            if k in kw:
                kw[k] = int(kw[k])
        return cls(**kw)


#: The paper's Table I configuration (AWR2243, 76 GHz).
TABLE_I = RadarConfig()
