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

Doppler de-aliasing (:func:`estimate_omega_dealiased`): the measured
Doppler is ambiguous modulo ``2 max_doppler_mps``; each velocity wrap ``k``
changes the TDM phase of transmitter slot ``m`` by ``2 pi k m / n_tx``, so
only the right wrap makes the transmitters' channels line up. The hypothesis
whose angle spectrum peaks highest is kept (the standard TDM-MIMO test).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import scipy.fft
from numpy.typing import NDArray
from scipy.signal import get_window

from ..errors import ConfigurationError, ValidationError
from ..data.radar_config import RadarConfig

__all__ = [
    "window",
    "check_cube",
    "range_doppler",
    "parabolic_offset",
    "doppler_of_bin",
    "tdm_phase_correction",
    "estimate_omega",
    "wrap_hypotheses",
    "estimate_omega_dealiased",
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


@lru_cache(maxsize=16)
def _loop_weights(n_loops: int) -> NDArray:
    w = np.full((1, n_loops), 1.0 / n_loops, dtype=np.float32)
    w.setflags(write=False)
    return w


def _loop_mean(x: NDArray) -> NDArray:
    """(S, V) complex64 mean over the loops of an (S, L, V) complex64 cube."""
    s, l, v = x.shape
    flat = np.ascontiguousarray(x).view(np.float32).reshape(s, l, 2 * v)
    return np.matmul(_loop_weights(l), flat).reshape(s, 2 * v).view(np.complex64)


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
    # Windows on the interleaved real and imaginary parts: a float32 product
    # (``x * w2`` would cast the window to complex first, 1.5x slower; the
    # numbers are the same, up to the sign of zeros).
    xc = np.ascontiguousarray(x)
    xw = np.empty_like(xc)
    np.multiply(xc.view(np.float32), w2, out=xw.view(np.float32))
    spec = scipy.fft.fft(xw, axis=0, workers=1, overwrite_x=True)
    if range_bins is not None:
        spec = spec[range_bins]
    if clutter_removal:
        # Loop mean of the range spectrum (range window only), removed in the
        # Doppler domain through the Doppler window's DFT.
        # (the loop mean as a float32 matrix product over the interleaved
        # real/imaginary parts: about 10x faster than ``x.mean(axis=1)``)
        wr = window(range_window, s)
        mean = _loop_mean(x) * wr[:, None]
        mean = scipy.fft.fft(mean, axis=0, workers=1, overwrite_x=True)
        if range_bins is not None:
            mean = mean[range_bins]
    spec = scipy.fft.fft(spec, axis=1, workers=1, overwrite_x=True)
    if clutter_removal:
        for b, val in zip(wbins, wvals):  # a few bins; basic slices, no copies
            spec[:, b, :] -= mean * val
    # |X|^2 summed over the channels: squares of the interleaved real and
    # imaginary parts times a ones vector (a float32 matrix product, about
    # 3x faster than an einsum).
    power = np.square(spec.view(np.float32)) @ _ones32(2 * v)
    return spec, power


@lru_cache(maxsize=16)
def _ones32(n: int) -> NDArray:
    o = np.ones(n, dtype=np.float32)
    o.setflags(write=False)
    return o


def parabolic_offset(left: NDArray, centre: NDArray, right: NDArray) -> NDArray:
    """Sub-bin offset of a peak from three log-power samples, in ``[-0.5, 0.5]``.

    The vertex of the parabola through ``(-1, left), (0, centre), (1, right)``:
    ``0.5 (left - right) / (left - 2 centre + right)``; 0 where the three
    points are not a peak (non-negative curvature).
    """
    left, centre, right = (np.asarray(a, dtype=float) for a in (left, centre, right))
    den = left - 2.0 * centre + right
    ok = den < 0  # False for NaN too
    off = np.zeros(den.shape)
    off[ok] = 0.5 * (left[ok] - right[ok]) / den[ok]
    return np.clip(off, -0.5, 0.5, out=off)


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


def _angle_peaks(corrected: NDArray, config: RadarConfig, angle_window: str, n_fft: int):
    """Angle spectra of TDM-corrected snapshots (..., n_virtual): the peak
    bin, the power spectrum and the peak power, over the last axis."""
    az = corrected[..., list(config.azimuth_channels)] * window(angle_window, config.n_azimuth)
    spec = np.fft.fft(az, n=n_fft, axis=-1)
    pw = spec.real**2 + spec.imag**2
    peak = np.argmax(pw, axis=-1)
    return peak, pw, np.take_along_axis(pw, peak[..., None], axis=-1)[..., 0]


def _omega_of_peak(pw: NDArray, peak: NDArray, n_fft: int) -> tuple[NDArray, NDArray]:
    rows = np.arange(pw.shape[0])
    lp = np.log(pw[rows[:, None], (peak[:, None] + np.array([-1, 0, 1])) % n_fft] + 1e-30)
    off = parabolic_offset(lp[:, 0], lp[:, 1], lp[:, 2])
    omega = 2.0 * np.pi * (peak + off) / n_fft
    omega = (omega + np.pi) % (2.0 * np.pi) - np.pi
    total = pw.sum(axis=1)
    share = np.zeros(rows.size)
    ok = total > 0
    share[ok] = pw[rows, peak][ok] / total[ok]
    return omega, share


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
    if snapshots.shape[0] == 0:
        return np.zeros(0), np.zeros(0)
    corrected = snapshots * tdm_phase_correction(doppler_mps, config)
    peak, pw, _ = _angle_peaks(corrected, config, angle_window, int(n_fft))
    return _omega_of_peak(pw, peak, int(n_fft))


def wrap_hypotheses(max_wraps: int) -> NDArray:
    """Velocity wraps ``k`` tried by :func:`estimate_omega_dealiased`, in the
    order that wins ties: ``0, -1, 1, -2, 2, ...``."""
    m = int(max_wraps)
    return np.array([0] + [s * k for k in range(1, m + 1) for s in (-1, 1)], dtype=np.int64)


def estimate_omega_dealiased(
    snapshots: NDArray,
    doppler_mps: NDArray,
    config: RadarConfig,
    *,
    max_wraps: int = 1,
    angle_window: str = "boxcar",
    n_fft: int = 64,
    dealias: NDArray | None = None,
) -> tuple[NDArray, NDArray, NDArray]:
    """:func:`estimate_omega` with TDM-MIMO Doppler de-aliasing.

    The measured Doppler ``v`` in ``[-v_max, v_max)`` (``v_max =
    config.max_doppler_mps``) stands for any ``v + 2 k v_max``. The TDM phase
    of transmitter slot ``m`` differs between the hypotheses by ``2 pi k m /
    n_tx``, so only the right ``k`` makes the azimuth channels of different
    transmitters line up: for each ``k`` in ``-max_wraps..max_wraps`` the
    channels are corrected with ``v + 2 k v_max`` and the hypothesis whose
    angle spectrum peaks highest is kept (ties, e.g. hypotheses that
    differ by a multiple of ``n_tx`` or a single-transmitter azimuth array,
    go to the smallest ``|v + 2 k v_max|``).

    dealias : (K,) bool, the cells to de-alias (default all); the others
        keep the measured Doppler and get :func:`estimate_omega`'s angle
        (the same numbers; one batch instead of two calls).

    Returns ``omega_rad (K,)``, the peak's share ``(K,)`` and the de-aliased
    Doppler ``(K,)`` (m/s).
    """
    v = np.asarray(doppler_mps, dtype=float)
    k_all = wrap_hypotheses(max_wraps)
    if dealias is not None:
        dealias = np.asarray(dealias, dtype=bool)
        if dealias.shape != v.shape:
            raise ValidationError(f"dealias has shape {dealias.shape}; doppler_mps has {v.shape}")
    if snapshots.shape[0] == 0 or k_all.size == 1 or (dealias is not None
                                                      and not dealias.any()):
        omega, share = estimate_omega(snapshots, v, config, angle_window=angle_window,
                                      n_fft=n_fft)
        return omega, share, v.copy()
    cand = v[None, :] + (2.0 * config.max_doppler_mps) * k_all[:, None]      # (H, K)
    corrected = snapshots[None, :, :] * tdm_phase_correction(cand.ravel(), config).reshape(
        k_all.size, v.size, -1)
    peak, pw, top = _angle_peaks(corrected, config, angle_window, int(n_fft))  # (H, K)
    # Near-ties (relative 1e-6) go to the slowest hypothesis.
    order = np.argsort(np.abs(cand), axis=0, kind="stable")
    top_sorted = np.take_along_axis(top, order, axis=0)
    best_sorted = np.argmax(top_sorted >= top_sorted.max(axis=0) * (1.0 - 1e-6), axis=0)
    best = order[best_sorted, np.arange(v.size)]
    if dealias is not None:
        best[~dealias] = 0  # hypothesis k = 0 (wrap_hypotheses starts with it)
    rows = np.arange(v.size)
    omega, share = _omega_of_peak(pw[best, rows], peak[best, rows], int(n_fft))
    return omega, share, cand[best, rows]
