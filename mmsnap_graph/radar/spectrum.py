"""Range-Doppler processing of a raw ADC cube and angle estimation per cell.

The cube of one frame is ``(n_samples, n_loops, n_virtual)`` complex
(:mod:`mmsnap_graph.data.radar_config`). The chain (paper section II-A):

1. **Range FFT** over fast time with a window from
   ``scipy.signal.get_window``; bin ``k`` is range ``k * range_resolution_m``
   (complex ADC: every bin up to ``max_range_m`` is a distinct range).
2. **Static clutter removal**: the mean over the chirp loops of each range
   bin and virtual channel is subtracted (zero-Doppler returns: walls,
   furniture, the radar's own leakage).
3. **Doppler FFT** over the loops with its window. Bin ``l`` (unshifted,
   ``l >= n_loops / 2`` meaning negative) is radial velocity
   ``l * doppler_resolution_mps``, positive = receding.
4. **Non-coherent integration** of ``|X|^2`` over the virtual channels: the
   range-Doppler power map that the CFAR detector runs on.

For speed the range and Doppler windows are applied together to the raw
cube, and clutter removal is applied in the Doppler domain: subtracting the
loop mean ``m`` before the Doppler window and FFT is the same as subtracting
``m * W[l]`` from the spectrum, ``W`` the DFT of the Doppler window, which
is non-zero on a few bins only (3 for Hann). The result is identical to the
textbook order (range FFT, subtract the mean, window, Doppler FFT).

Angle (per detected cell only): TDM-MIMO transmitters fire one chirp period
apart, so a target of radial velocity ``V`` adds the phase
``4 pi V m T_c / lambda`` to the channels of transmitter ``m``; it is
removed with ``V`` from the cell's (interpolated) Doppler, then the
``azimuth_channels`` (the uniform lambda/2 array, in position order) are
windowed, zero-padded and transformed; the spatial frequency
``omega = pi sin(theta)`` is the interpolated peak (a parabola through the
log power of the peak bin and its neighbours).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import scipy.fft
from numpy.typing import NDArray
from scipy.signal import get_window

from ..errors import ConfigurationError
from ..data.radar_config import RadarConfig

__all__ = [
    "window",
    "check_cube",
    "range_doppler",
    "parabolic_offset",
    "doppler_of_bin",
    "tdm_phase_correction",
    "estimate_omega",
]


@lru_cache(maxsize=64)
def _window_cached(name: str, n: int) -> NDArray:
    try:
        w = get_window(name, n, fftbins=True)
    except (ValueError, TypeError) as exc:
        raise ConfigurationError(f"window {name!r} is not a scipy.signal window: {exc}") from exc
    w = np.asarray(w, dtype=np.float32)
    w.setflags(write=False)
    return w


def window(name: str, n: int) -> NDArray:
    """(n,) float32 periodic window ``scipy.signal.get_window(name, n)``
    (cached, read-only)."""
    return _window_cached(str(name), int(n))


def check_cube(cube: NDArray, config: RadarConfig, *, frames: bool = False) -> NDArray:
    """The cube as a complex64 array, or a :class:`ConfigurationError` naming
    the expected and actual shapes. ``frames``: expect ``(F, *cube_shape)``."""
    arr = np.asarray(cube)
    want = config.cube_shape
    shape_ok = (arr.ndim == 4 and arr.shape[1:] == want) if frames else arr.shape == want
    if not shape_ok:
        lead = "(F, " if frames else "("
        raise ConfigurationError(
            f"cube shape {arr.shape} disagrees with its radar configuration: expected "
            f"{lead}{', '.join(map(str, want))}) = (n_samples={config.n_samples}, "
            f"n_loops={config.n_loops}, n_virtual={config.n_virtual})")
    if not np.iscomplexobj(arr):
        if not np.issubdtype(arr.dtype, np.number):
            raise ConfigurationError(f"cube must be numeric, got dtype {arr.dtype}")
    return arr.astype(np.complex64, copy=False)


@lru_cache(maxsize=32)
def _rd_weights(n_samples: int, n_loops: int, range_window: str, doppler_window: str):
    wr = window(range_window, n_samples)
    wd = window(doppler_window, n_loops)
    w2 = (wr[:, None] * wd[None, :]).astype(np.float32)[:, :, None]
    # DFT of the Doppler window; only its non-negligible bins are needed.
    wd_fft = np.fft.fft(wd.astype(float))
    bins = np.flatnonzero(np.abs(wd_fft) > 1e-6 * np.abs(wd_fft).max())
    return w2, bins, wd_fft[bins].astype(np.complex64)


def range_doppler(
    cube: NDArray,
    config: RadarConfig,
    *,
    range_window: str = "hann",
    doppler_window: str = "hann",
    clutter_removal: bool = True,
    range_bins: slice | None = None,
) -> tuple[NDArray, NDArray]:
    """Range and Doppler FFTs of one frame, with static clutter removal.

    cube : (n_samples, n_loops, n_virtual) complex (checked against ``config``).
    range_bins : keep only these range bins (e.g. ``slice(6, 400)``); default all.
    Returns ``spectrum (K, n_loops, n_virtual) complex64`` (Doppler unshifted)
    and the non-coherently integrated power map ``power (K, n_loops) float32``,
    ``K`` the number of kept range bins.
    """
    x = check_cube(cube, config)
    s, l, v = x.shape
    w2, wbins, wvals = _rd_weights(s, l, str(range_window), str(doppler_window))
    spec = scipy.fft.fft(x * w2, axis=0, workers=1, overwrite_x=True)
    if range_bins is not None:
        spec = spec[range_bins]
    if clutter_removal:
        # Loop mean of the range spectrum (range window only), removed in the
        # Doppler domain through the Doppler window's DFT.
        wr = window(range_window, s)
        mean = scipy.fft.fft(x.mean(axis=1) * wr[:, None], axis=0, workers=1)
        if range_bins is not None:
            mean = mean[range_bins]
    spec = scipy.fft.fft(spec, axis=1, workers=1, overwrite_x=True)
    if clutter_removal:
        spec[:, wbins, :] -= mean[:, None, :] * wvals[None, :, None]
    flat = spec.view(np.float32)
    power = np.einsum("ijk,ijk->ij", flat, flat)
    return spec, power


def parabolic_offset(left: NDArray, centre: NDArray, right: NDArray) -> NDArray:
    """Sub-bin offset of a peak from three log-power samples, in ``[-0.5, 0.5]``.

    The vertex of the parabola through ``(-1, left), (0, centre), (1, right)``:
    ``0.5 (left - right) / (left - 2 centre + right)``; 0 where the three
    points are not a peak (non-negative curvature).
    """
    left, centre, right = (np.asarray(a, dtype=float) for a in (left, centre, right))
    den = left - 2.0 * centre + right
    with np.errstate(divide="ignore", invalid="ignore"):
        off = np.where(den < 0, 0.5 * (left - right) / den, 0.0)
    return np.clip(np.nan_to_num(off), -0.5, 0.5)


def doppler_of_bin(bin_float: NDArray, config: RadarConfig) -> NDArray:
    """Radial velocity (m/s) of an (interpolated) unshifted Doppler bin,
    wrapped to ``[-max_doppler_mps, max_doppler_mps)``."""
    n = config.n_loops
    b = (np.asarray(bin_float, dtype=float) + n / 2.0) % n - n / 2.0
    return b * config.doppler_resolution_mps


def tdm_phase_correction(doppler_mps: NDArray, config: RadarConfig) -> NDArray:
    """(K, n_virtual) complex64 factors removing the TDM-MIMO Doppler phase:
    ``exp(-j 4 pi V m T_c / lambda)`` on the channels of transmitter ``m``."""
    tx = np.repeat(np.arange(config.n_tx), config.n_rx).astype(float)
    ph = (-4.0 * np.pi * config.chirp_period_s / config.wavelength_m) \
        * np.asarray(doppler_mps, dtype=float)[:, None] * tx[None, :]
    return np.exp(1j * ph).astype(np.complex64)


def estimate_omega(
    snapshots: NDArray,
    doppler_mps: NDArray,
    config: RadarConfig,
    *,
    angle_window: str = "boxcar",
    n_fft: int = 64,
) -> tuple[NDArray, NDArray]:
    """Spatial frequency of the strongest angle peak of each cell.

    snapshots : (K, n_virtual) complex, the range-Doppler spectrum of each
        detected cell over the virtual channels.
    doppler_mps : (K,) radial velocity of each cell (for the TDM correction).
    Returns ``omega_rad (K,)`` in ``[-pi, pi)`` and the peak's share of the
    angle spectrum's power ``(K,)`` (1 for a single clean plane wave).
    """
    k = snapshots.shape[0]
    if k == 0:
        return np.zeros(0), np.zeros(0)
    corrected = snapshots * tdm_phase_correction(doppler_mps, config)
    az = corrected[:, list(config.azimuth_channels)] * window(angle_window, config.n_azimuth)
    spec = np.fft.fft(az, n=n_fft, axis=1)
    pw = spec.real**2 + spec.imag**2
    peak = np.argmax(pw, axis=1)
    rows = np.arange(k)
    lp = np.log(pw + 1e-30)
    off = parabolic_offset(lp[rows, (peak - 1) % n_fft], lp[rows, peak], lp[rows, (peak + 1) % n_fft])
    omega = 2.0 * np.pi * (peak + off) / n_fft
    omega = (omega + np.pi) % (2.0 * np.pi) - np.pi
    with np.errstate(invalid="ignore", divide="ignore"):
        share = np.nan_to_num(pw[rows, peak] / (pw.sum(axis=1) + 1e-30))
    return omega, share
