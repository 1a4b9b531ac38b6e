"""Raw-ADC radar cube synthesis for an FMCW TDM-MIMO radar (point scatterers).

Each scatterer ``k`` at local position ``p_k`` (x along the array axis, y
broadside) with local velocity ``v_k`` contributes, to ADC sample ``n`` of the
chirp that transmitter ``m`` fires in loop ``l``, received on receiver ``q``::

    a_k exp(j 2 pi f_b,k n / fs)                         fast time (range)
        * exp(j 4 pi V_k t_{l,m} / lambda)               slow time (Doppler)
        * exp(j pi (tx_m + rx_q) sin(theta_k))           space (azimuth)

with ``R_k = |p_k|``, ``V_k = <v_k, p_k> / R_k`` (positive = receding),
``sin(theta_k) = x_k / R_k`` (so the spatial frequency is
``omega = pi sin(theta)``, docs/CONVENTIONS.md), the beat frequency
``f_b = 2 (slope R_k + carrier V_k) / c`` (range plus the small
range-Doppler coupling), the chirp start time within the frame
``t_{l,m} = (l n_tx + m) chirp_period_s`` (TDM-MIMO: every transmitter fires
at its own time, so the Doppler phase differs between transmitters; the
signal chain corrects it), and antenna positions ``tx_m``, ``rx_q`` in units
of half a wavelength (:class:`~mmsnap_graph.data.radar_config.RadarConfig`). The
carrier phase of each scatterer is folded into its complex amplitude; the
sign convention consistent with the Doppler term (phase ``4 pi R(t) /
lambda`` growing with range) is ``a_k = |a_k| exp(+j 4 pi R_k / lambda)``,
which keeps the phase continuous from frame to frame. Nothing in the chain
depends on it (each frame is processed on its own). Elevation is zero for every target, so the raised
transmitter's channels see only their azimuth phase.

The range advances with the radial velocity through the Doppler phase
(``R(t) = R_k + V_k t``); the resulting range migration within a frame (at
most ``V * 22 ms``, well below one 3.5 cm range cell for walking speeds) is
neglected in the fast-time term. Scatterers at or beyond the unambiguous
range ``config.max_range_m`` are dropped (the ADC's anti-aliasing filter
removes them on real hardware).

The cube is built from separable per-axis phasors: a fast-time matrix
``(M, n_samples)`` times a slow-time-and-space matrix ``(M, n_loops *
n_virtual)``, one matrix product per frame; no loop over samples or
scatterers.

Amplitude and noise scaling
---------------------------
``noise_std`` is the standard deviation of the complex thermal noise per ADC
sample (``E|n|^2 = noise_std^2``). A scatterer of complex amplitude ``a``
then has, after an unwindowed 2D (range, Doppler) FFT, a per-virtual-channel
SNR of ``|a|^2 n_samples n_loops / noise_std^2`` (coherent gain
``n_samples * n_loops``). :func:`scatterer_amplitude` sets ``|a|`` from the
radar equation (``|a| ~ sqrt(rcs) / R^2``) anchored at
:data:`REFERENCE_SNR_DB` = 20 dB for a 1 m^2 target at 10 m. A human torso
(RCS about 0.5 m^2 at 77 GHz) then has about 29 dB at 5 m and 17 dB at 10 m
per channel after the 2D FFT, and about 10 dB more after non-coherent
integration over the 12 virtual channels: consistent with the detection
ranges of 15-20 m reported for people with AWR-class radars. Limbs
(0.05-0.1 m^2 each) come out 7-10 dB below the torso.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import ConfigurationError, ValidationError
from ..data.radar_config import SPEED_OF_LIGHT_MPS, RadarConfig
from .._validation import as_float_array, check_finite

__all__ = [
    "REFERENCE_SNR_DB",
    "REFERENCE_RANGE_M",
    "REFERENCE_RCS_M2",
    "synthesize_cube",
    "synthesize_cubes",
    "scatterer_amplitude",
    "post_fft_snr_db",
]

#: Per-virtual-channel SNR after an unwindowed 2D FFT of a 1 m^2 target at 10 m.
REFERENCE_SNR_DB = 20.0
REFERENCE_RANGE_M = 10.0
REFERENCE_RCS_M2 = 1.0


def scatterer_amplitude(
    config: RadarConfig,
    rcs_m2: ArrayLike,
    range_m: ArrayLike,
    *,
    noise_std: float = 1.0,
    reference_snr_db: float = REFERENCE_SNR_DB,
) -> NDArray:
    """Real amplitude of point scatterers from the radar equation.

    ``SNR_2D = reference_snr_db + 10 log10(rcs / 1 m^2) - 40 log10(R / 10 m)``
    (per virtual channel, after an unwindowed range-Doppler FFT), and
    ``|a| = noise_std * sqrt(10^(SNR_2D / 10) / (n_samples n_loops))``.

    rcs_m2, range_m : broadcastable float arrays (m^2, m).
    Returns the amplitudes, broadcast shape, float.
    """
    rcs = check_finite(as_float_array(rcs_m2, "rcs_m2"), "rcs_m2")
    rng_m = check_finite(as_float_array(range_m, "range_m"), "range_m")
    if np.any(rcs < 0):
        raise ValidationError(f"rcs_m2 must be >= 0, got {rcs.min()!r}")
    if np.any(rng_m <= 0):
        raise ValidationError(f"range_m must be > 0, got {rng_m.min()!r}")
    snr_lin = (10.0 ** (reference_snr_db / 10.0) * (rcs / REFERENCE_RCS_M2)
               * (REFERENCE_RANGE_M / rng_m) ** 4)
    return float(noise_std) * np.sqrt(snr_lin / (config.n_samples * config.n_loops))


def post_fft_snr_db(config: RadarConfig, amplitude: ArrayLike, noise_std: float) -> NDArray:
    """Per-channel SNR (dB) after an unwindowed 2D FFT of a scatterer of
    complex amplitude ``amplitude`` in noise of std ``noise_std`` per sample."""
    a2 = np.abs(np.asarray(amplitude)) ** 2
    with np.errstate(divide="ignore"):
        return 10.0 * np.log10(a2 * config.n_samples * config.n_loops / float(noise_std) ** 2)


def _scatterers(positions, velocities, amplitudes, what: str):
    p = check_finite(as_float_array(positions, f"{what}positions_local_m"),
                     f"{what}positions_local_m")
    if p.ndim != 2 or p.shape[1] != 2:
        raise ValidationError(f"{what}positions_local_m must have shape (M, 2), got {p.shape}")
    m = p.shape[0]
    if velocities is None:
        v = np.zeros((m, 2))
    else:
        v = check_finite(as_float_array(velocities, f"{what}velocities_local_mps"),
                         f"{what}velocities_local_mps")
        if v.shape != (m, 2):
            raise ValidationError(f"{what}velocities_local_mps must have shape ({m}, 2) like "
                                  f"positions, got {v.shape}")
    a = np.asarray(amplitudes)
    if not (np.issubdtype(a.dtype, np.number)):
        raise ValidationError(f"{what}amplitudes must be numeric, got dtype {a.dtype}")
    a = np.broadcast_to(a, (m,)) if a.ndim == 0 else a
    if a.shape != (m,):
        raise ValidationError(f"{what}amplitudes must have shape ({m},) like positions, "
                              f"got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValidationError(f"{what}amplitudes must be finite")
    r = np.hypot(p[:, 0], p[:, 1])
    if np.any(r <= 0):
        raise ValidationError(f"{what}positions_local_m must not be at the radar (range 0), "
                              f"got row {int(np.argmin(r))}")
    return p, v, a.astype(np.complex128), r


class _Axes:
    """Per-configuration constant vectors (computed once per batch)."""

    __slots__ = ("n_idx", "chirp_t", "virt_pos", "shape", "fs", "lam", "max_r")

    def __init__(self, config: RadarConfig) -> None:
        s, l, v = config.cube_shape
        n_tx, n_rx = config.n_tx, config.n_rx
        self.shape = (s, l, v)
        self.fs = config.sample_rate_hz
        self.lam = config.wavelength_m
        self.max_r = config.max_range_m
        self.n_idx = np.arange(s, dtype=float)
        # Start time of each (loop, virtual channel)'s chirp: the virtual
        # channel's transmitter decides when in the loop it fires.
        tx_of_virtual = np.repeat(np.arange(n_tx), n_rx)
        self.chirp_t = ((np.arange(l)[:, None] * n_tx + tx_of_virtual[None, :])
                        * config.chirp_period_s)                         # (L, V)
        self.virt_pos = config.virtual_azimuth_half_wl                   # (V,)


def _cube_from(axes: _Axes, config: RadarConfig, p, v, a, r, out: NDArray) -> None:
    """Add the scatterers' signal into ``out`` (S, L, V) complex64."""
    keep = r < axes.max_r
    if not np.all(keep):
        p, v, a, r = p[keep], v[keep], a[keep], r[keep]
    if r.size == 0:
        return
    sin_t = p[:, 0] / r
    v_rad = np.sum(v * p, axis=1) / r
    f_beat = 2.0 * (config.slope_hz_per_s * r + config.carrier_hz * v_rad) / SPEED_OF_LIGHT_MPS
    # Fast time: (M, S), carrying the amplitude.
    fast = a[:, None] * np.exp((2j * np.pi / axes.fs) * f_beat[:, None] * axes.n_idx[None, :])
    # Slow time and space: (M, L, V) -> (M, L*V).
    slow_phase = (4.0 * np.pi / axes.lam) * v_rad[:, None, None] * axes.chirp_t[None]
    space_phase = np.pi * sin_t[:, None] * axes.virt_pos[None, :]
    sv = np.exp(1j * (slow_phase + space_phase[:, None, :]))
    s, l, nv = axes.shape
    prod = fast.astype(np.complex64).T @ sv.reshape(r.size, l * nv).astype(np.complex64)
    out += prod.reshape(s, l, nv)


def _add_noise(out: NDArray, noise_std: float, rng: np.random.Generator) -> None:
    if noise_std > 0:
        scale = np.float32(noise_std / np.sqrt(2.0))
        view = out.view(np.float32)  # interleaved real/imag, same shape x2 on last axis
        noise = rng.standard_normal(view.shape, dtype=np.float32)
        noise *= scale
        view += noise


def _check_common(config, noise_std, clutter):
    if not isinstance(config, RadarConfig):
        raise ConfigurationError(f"config must be a RadarConfig, got {type(config).__name__}")
    ns = float(noise_std)
    if not (np.isfinite(ns) and ns >= 0):
        raise ValidationError(f"noise_std must be finite and >= 0, got {noise_std!r}")
    if clutter is None:
        return ns, None
    try:
        c_pos, c_amp = clutter
    except (TypeError, ValueError) as exc:
        raise ValidationError("clutter must be a pair (positions_local_m (C, 2), "
                              "amplitudes (C,)) or None") from exc
    return ns, _scatterers(c_pos, None, c_amp, "clutter ")


def synthesize_cube(
    config: RadarConfig,
    positions_local_m: ArrayLike,
    velocities_local_mps: ArrayLike,
    amplitudes: ArrayLike,
    *,
    rng: np.random.Generator,
    noise_std: float = 1.0,
    clutter: tuple[ArrayLike, ArrayLike] | None = None,
) -> NDArray:
    """One frame's raw ADC cube from point scatterers (module docstring).

    config : the chirp and array configuration.
    positions_local_m : (M, 2) float, scatterers in the node's local frame
        at the frame's start (x along the array axis, y broadside).
    velocities_local_mps : (M, 2) float, their velocities (local frame).
    amplitudes : (M,) real or complex amplitude per ADC sample (see
        :func:`scatterer_amplitude`); a complex value sets the carrier phase.
    rng : the random generator for the thermal noise.
    noise_std : std of the complex Gaussian noise per ADC sample (0 = none).
    clutter : optional static (zero-Doppler) scatterers
        ``(positions_local_m (C, 2), amplitudes (C,))``, identical in every
        frame that passes the same values.
    Returns (n_samples, n_loops, n_virtual) complex64.
    """
    ns, clut = _check_common(config, noise_std, clutter)
    p, v, a, r = _scatterers(positions_local_m, velocities_local_mps, amplitudes, "")
    axes = _Axes(config)
    out = np.zeros(axes.shape, dtype=np.complex64)
    _cube_from(axes, config, p, v, a, r, out)
    if clut is not None:
        _cube_from(axes, config, *clut, out)
    _add_noise(out, ns, rng)
    return out


def synthesize_cubes(
    config: RadarConfig,
    positions_local_m: Sequence[ArrayLike] | ArrayLike,
    velocities_local_mps: Sequence[ArrayLike] | ArrayLike,
    amplitudes: Sequence[ArrayLike] | ArrayLike,
    *,
    rng: np.random.Generator,
    noise_std: float = 1.0,
    clutter: tuple[ArrayLike, ArrayLike] | None = None,
    out: NDArray | None = None,
) -> NDArray:
    """Cubes of ``F`` frames: :func:`synthesize_cube` per frame, batched.

    positions_local_m, velocities_local_mps : length-F sequences of (M_f, 2)
        arrays (M_f may differ per frame), or (F, M, 2) arrays.
    amplitudes : length-F sequence of (M_f,) arrays, or an (F, M) array.
    clutter : static scatterers shared by every frame (see :func:`synthesize_cube`).
    out : optional preallocated (F, n_samples, n_loops, n_virtual) complex64
        array to fill (e.g. a memory map); it is overwritten.
    Returns (F, n_samples, n_loops, n_virtual) complex64.
    """
    ns, clut = _check_common(config, noise_std, clutter)
    n_frames = len(positions_local_m)
    if len(velocities_local_mps) != n_frames or len(amplitudes) != n_frames:
        raise ValidationError(
            f"positions ({n_frames} frames), velocities ({len(velocities_local_mps)}) and "
            f"amplitudes ({len(amplitudes)}) must cover the same frames")
    axes = _Axes(config)
    shape = (n_frames, *axes.shape)
    if out is None:
        out = np.zeros(shape, dtype=np.complex64)
    else:
        if out.shape != shape or out.dtype != np.complex64:
            raise ValidationError(f"out must be complex64 with shape {shape}, got "
                                  f"{out.dtype} {out.shape}")
    # The clutter's contribution is the same in every frame: compute it once.
    clutter_cube = None
    if clut is not None:
        clutter_cube = np.zeros(axes.shape, dtype=np.complex64)
        _cube_from(axes, config, *clut, clutter_cube)
    frame_buf = np.empty(axes.shape, dtype=np.complex64)
    for f in range(n_frames):
        p, v, a, r = _scatterers(positions_local_m[f], velocities_local_mps[f], amplitudes[f],
                                 f"frame {f}: ")
        if clutter_cube is None:
            frame_buf.fill(0)
        else:
            frame_buf[...] = clutter_cube
        _cube_from(axes, config, p, v, a, r, frame_buf)
        _add_noise(frame_buf, ns, rng)
        out[f] = frame_buf
    return out
