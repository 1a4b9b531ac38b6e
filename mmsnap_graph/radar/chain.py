"""The per-node signal chain: raw ADC cube -> point cloud -> torso centroids
(paper section II-A; tracking is :mod:`mmsnap_graph.tracking.ekf`).

Per frame (:func:`point_cloud_of_cube`):

1. range and Doppler FFTs with static clutter removal and the power map
   (:func:`mmsnap_graph.radar.spectrum.range_doppler`);
2. candidate cells: local maxima of the power map (3 x 3, Doppler periodic;
   "peak grouping": one detection per peak, not one per cell of its main
   lobe) above a pre-screen level ``prescreen_db`` below the CFAR threshold
   that the map's median noise would give; cells in the clutter notch
   (Doppler bin 0, when clutter removal is on) and closer than
   ``min_range_m`` are skipped;
3. 2D OS-CFAR at those cells (:func:`mmsnap_graph.radar.cfar.os_cfar_detections`,
   identical to the whole-map ``scipy.ndimage.rank_filter`` evaluation,
   ``cfar_method="full"``, which is about 5x slower). The pre-screen only
   drops peaks whose local noise estimate would have to be ``prescreen_db``
   below the map's median to pass;
4. range and Doppler refined by parabolic interpolation of the log power,
   angle by the TDM-corrected, interpolated angle FFT per detected cell,
   the Doppler de-aliased by the TDM hypothesis test (``doppler_wraps``,
   :func:`~mmsnap_graph.radar.spectrum.estimate_omega_dealiased`); ``snr_db`` is the cell's power over the local noise estimate (OS statistic
   scaled to the mean noise power of a cell of the channel-integrated map).

False alarms: on noise-only Table I frames the chain's rate is close to the
design rate ``pfa`` per searched cell (tests/radar/test_chain.py checks it
within 0.7-1.6 of the design): the windows
correlate neighbouring cells (more false alarms than for independent cells,
for which :mod:`.cfar`'s threshold is exact) and peak grouping keeps one per
local maximum (fewer).

Speed (``benchmarks/bench_chain.py``): the constants of a radar and chain
configuration (range interval, CFAR factor and noise scale, padding) are
computed once per :func:`process_cubes` call, the 3 x 3 local maxima are two
separable 3-cell maxima of the padded map, the OS statistic is taken only for
peaks that a count of a subset of their training cells cannot rule out, and
the angle FFTs of all cells and Doppler hypotheses are one batch; the point
clouds are the same to the last bit as with the straightforward evaluation.

Frames that cannot be processed give no detections and a flag, never NaN:
non-finite samples, all-zero cubes (no noise to set a threshold), and, when
``adc_full_scale`` is set, frames with more than ``max_saturated_fraction``
of their samples at full scale.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache
from typing import Iterable

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from .._validation import check_count
from ..errors import ConfigurationError, ValidationError
from ..data.recording import Detections
from ..data.results import Status
from .cfar import (
    CfarConfig,
    footprint,
    os_cfar_2d,
    os_cfar_alpha,
    os_cfar_detections,
    os_cfar_noise_scale,
    pad_map,
)
from .cluster import ClusterConfig, torso_centroids
from ..data.radar_config import RadarConfig
from .spectrum import (
    check_cube,
    doppler_of_bin,
    estimate_omega,
    estimate_omega_dealiased,
    parabolic_offset,
    range_doppler,
    window,
)

__all__ = [
    "ChainConfig",
    "ChainResult",
    "point_cloud_of_cube",
    "detect_frame",
    "process_cubes",
    "unambiguous_speed_mps",
    "doppler_near_limit",
    "DEFAULT_MIN_RANGE_M",
]

#: Default start of the processed range (m). Real boards leave a near-field
#: residue of the transmitter-receiver leakage and the radome that survives
#: static clutter removal (on an AWR1843, a false centroid below a metre in
#: most frames); nothing closer than this is processed (docs/TI.md,
#: "Near-field leakage").
DEFAULT_MIN_RANGE_M = 0.9


#: Bounds of the chain's configuration. A TI radar has at most 12 virtual
#: antennas (more angle bins than 4096 resolve nothing and a 10^8 FFT asks for
#: gigabytes per frame); no mmWave radar sees beyond 10 km; 400 dB exceeds
#: any float's dynamic range (10^40).
MAX_ANGLE_FFT_SIZE = 4096
MAX_CHAIN_RANGE_M = 1e4
MAX_DB = 400.0


@dataclass(frozen=True, kw_only=True, slots=True)
class ChainConfig:
    """Signal-chain parameters (the radar's own parameters are a RadarConfig).

    range_window, doppler_window, angle_window : ``scipy.signal.get_window`` names.
    angle_fft_size : zero-padded angle FFT length.
    clutter_removal : subtract the loop mean (static clutter).
    min_range_m, max_range_m : processed range interval (max None = up to the
        radar's unambiguous range). The default minimum,
        :data:`DEFAULT_MIN_RANGE_M` = 0.9 m, clears the near-field leakage
        residue of real boards (0.72-0.78 m on an AWR1843); 0.3 m was the
        default before (simulated cubes have no leakage).
    doppler_wraps : TDM-MIMO Doppler de-aliasing: velocity wraps ``k`` in
        ``-doppler_wraps..doppler_wraps`` are tested per detection
        (:func:`~mmsnap_graph.radar.spectrum.estimate_omega_dealiased`),
        extending the unambiguous speed to ``(2 doppler_wraps + 1)
        max_doppler_mps``; 0 = off (the measured Doppler, aliased beyond
        ``max_doppler_mps``). Default 1: with 3 transmitters, the wraps that
        can be told apart.
    dealias_min_snr_db : detections weaker than this keep the measured
        (wrapped) Doppler: on weak points the hypothesis test picks a wrong
        wrap now and then (docs/TI.md, "Doppler de-aliasing", gives the
        figures). Default 12 dB.
    near_limit_fraction : detections whose speed is at least this fraction
        of :func:`unambiguous_speed_mps` are flagged
        (``ChainResult.doppler_near_limit``): they may be aliased.
    cfar : OS-CFAR parameters; cfar_method : ``"cells"`` (fast) or ``"full"``.
    prescreen_db : pre-screen margin below the threshold the map's own rank
        statistic gives (dB).
    dynamic_range_db : cells weaker than the frame's energy ``sum |x|^2`` by
        more than this are float32 rounding residue, never detections.
    adc_full_scale, max_saturated_fraction : saturation check (off when None).
    cluster : torso-DBSCAN parameters.
    """

    range_window: str = "hann"
    doppler_window: str = "hann"
    angle_window: str = "boxcar"
    angle_fft_size: int = 64
    clutter_removal: bool = True
    min_range_m: float = DEFAULT_MIN_RANGE_M
    max_range_m: float | None = None
    doppler_wraps: int = 1
    dealias_min_snr_db: float = 12.0
    near_limit_fraction: float = 0.9
    cfar: CfarConfig = field(default_factory=CfarConfig)
    cfar_method: str = "cells"
    prescreen_db: float = 3.0
    dynamic_range_db: float = 90.0
    adc_full_scale: float | None = None
    max_saturated_fraction: float = 0.01
    cluster: ClusterConfig = field(default_factory=ClusterConfig)

    def __post_init__(self) -> None:
        for name in ("range_window", "doppler_window", "angle_window"):
            try:
                window(getattr(self, name), 8)
            except ConfigurationError as exc:
                raise ConfigurationError(f"{name}: {exc}") from None
        check_count(self.angle_fft_size, "angle_fft_size", 8, MAX_ANGLE_FFT_SIZE,
                    error=ConfigurationError)
        if not (np.isfinite(self.min_range_m) and 0 <= self.min_range_m <= MAX_CHAIN_RANGE_M):
            raise ConfigurationError(f"min_range_m={self.min_range_m!r} must be in "
                                     f"[0, {MAX_CHAIN_RANGE_M:g}] (metres)")
        if self.max_range_m is not None and not (
                isinstance(self.max_range_m, (int, float)) and not isinstance(self.max_range_m, bool)
                and self.min_range_m < self.max_range_m <= MAX_CHAIN_RANGE_M):
            raise ConfigurationError(f"max_range_m={self.max_range_m!r} must exceed "
                                     f"min_range_m={self.min_range_m!r} and be at most "
                                     f"{MAX_CHAIN_RANGE_M:g} (metres; unset: the radar's "
                                     "unambiguous range)")
        check_count(self.doppler_wraps, "doppler_wraps", 0, 8, error=ConfigurationError)
        if isinstance(self.dealias_min_snr_db, bool) or not (
                np.isfinite(self.dealias_min_snr_db) and abs(self.dealias_min_snr_db) <= MAX_DB):
            raise ConfigurationError(f"dealias_min_snr_db={self.dealias_min_snr_db!r} must be a "
                                     f"finite number within +-{MAX_DB:g} dB")
        if not (isinstance(self.near_limit_fraction, (int, float))
                and 0 < self.near_limit_fraction <= 1):
            raise ConfigurationError(f"near_limit_fraction={self.near_limit_fraction!r} must be "
                                     f"in (0, 1]")
        if not isinstance(self.cfar, CfarConfig):
            raise ConfigurationError(f"cfar must be a CfarConfig, got {type(self.cfar).__name__}")
        if not isinstance(self.cluster, ClusterConfig):
            raise ConfigurationError(f"cluster must be a ClusterConfig, got "
                                     f"{type(self.cluster).__name__}")
        if self.cfar_method not in ("cells", "full"):
            raise ConfigurationError(f"cfar_method={self.cfar_method!r} must be 'cells' or 'full'")
        if not (np.isfinite(self.dynamic_range_db) and 0 < self.dynamic_range_db <= MAX_DB):
            raise ConfigurationError(f"dynamic_range_db={self.dynamic_range_db!r} must be in "
                                     f"(0, {MAX_DB:g}] dB")
        if not (np.isfinite(self.prescreen_db) and 0 <= self.prescreen_db <= MAX_DB):
            raise ConfigurationError(f"prescreen_db={self.prescreen_db!r} must be in "
                                     f"[0, {MAX_DB:g}] dB")
        if self.adc_full_scale is not None and not (0 < self.adc_full_scale <= 1e12):
            raise ConfigurationError(f"adc_full_scale={self.adc_full_scale!r} must be > 0 and at "
                                     "most 1e12 (ADC counts; unset: no saturation check)")
        if not 0 <= self.max_saturated_fraction <= 1:
            raise ConfigurationError(f"max_saturated_fraction={self.max_saturated_fraction!r} "
                                     f"must be in [0, 1]")


@dataclass(frozen=True, kw_only=True, slots=True)
class ChainResult:
    """The chain's output for a sequence of frames.

    point_cloud, centroids : :class:`Detections` (frame numbers as given).
    frame : (F,) int processed frames; status : (F,) int,
    :class:`~mmsnap_graph.data.results.Status` codes (0, 6, 7 or 8).
    success : every frame was processed; message : a summary of the flags.
    doppler_near_limit : (K,) bool, one per point-cloud row: the speed is near
        the unambiguous speed (:func:`doppler_near_limit`), it may be aliased.
    """

    point_cloud: Detections
    centroids: Detections
    frame: NDArray
    status: NDArray
    success: bool
    message: str
    doppler_near_limit: NDArray = field(default_factory=lambda: np.zeros(0, bool))


def unambiguous_speed_mps(config: RadarConfig, chain: ChainConfig | None = None) -> float:
    """The largest speed the chain reports without aliasing (m/s):
    ``(2 chain.doppler_wraps + 1) * config.max_doppler_mps``. Pass it to
    :class:`~mmsnap_graph.tracking.ekf.EkfConfig` as ``doppler_wrap_mps``."""
    chain = ChainConfig() if chain is None else chain
    return float((2 * int(chain.doppler_wraps) + 1) * config.max_doppler_mps)


def doppler_near_limit(doppler_mps: NDArray, config: RadarConfig,
                       chain: ChainConfig | None = None) -> NDArray:
    """(K,) bool: ``|doppler_mps| >= near_limit_fraction *``
    :func:`unambiguous_speed_mps` (the speed may be aliased)."""
    chain = ChainConfig() if chain is None else chain
    v = np.abs(np.asarray(doppler_mps, dtype=float))
    return v >= chain.near_limit_fraction * unambiguous_speed_mps(config, chain)


def _range_slice(config: RadarConfig, chain: ChainConfig) -> slice:
    res = config.range_resolution_m
    lo = int(np.ceil(chain.min_range_m / res))
    hi = config.n_samples if chain.max_range_m is None else \
        min(config.n_samples, int(np.floor(chain.max_range_m / res)) + 1)
    if hi - lo < 3:
        raise ConfigurationError(
            f"the range interval [{chain.min_range_m}, {chain.max_range_m}] m keeps {hi - lo} "
            f"range bins of {res:.4f} m; at least 3 are needed")
    return slice(lo, hi)


def _frame_status(cube: NDArray, chain: ChainConfig) -> tuple[Status, float]:
    """The frame's status and its total energy ``sum |x|^2`` (one pass)."""
    flat = cube.view(np.float32).ravel()
    energy = float(np.dot(flat, flat))
    if not np.isfinite(energy):
        if np.all(np.isfinite(flat)):  # float32 overflow of finite samples
            energy = float(np.dot(flat.astype(float), flat.astype(float)))
        else:
            return Status.NON_FINITE_SAMPLES, 0.0
    if energy == 0.0:
        return Status.ALL_ZERO_CUBE, 0.0
    if chain.adc_full_scale is not None:
        frac = np.count_nonzero(np.abs(flat) >= chain.adc_full_scale) / flat.size
        if frac > chain.max_saturated_fraction:
            return Status.SATURATED, energy
    return Status.OK, energy


@lru_cache(maxsize=1)
def _default_chain() -> ChainConfig:
    return ChainConfig()


def _empty_cloud_arrays():
    z = np.zeros(0)
    return z, z, z, z


@dataclass(frozen=True, slots=True)
class _FramePlan:
    """The constants of the per-frame work for one radar and chain
    configuration (computed once, not per frame)."""

    rs: slice                # processed range bins
    alpha: float             # OS-CFAR threshold factor
    prescreen_factor: float  # 10^(-prescreen_db / 10)
    floor_factor: float      # 10^(-dynamic_range_db / 10)
    noise_scale: float       # E[Z_(k)] / E[cell]
    q_index: int             # rank of the pre-screen statistic in power[::2, ::2]
    hr: int                  # footprint half-sizes (the padding of the map)
    hd: int


@lru_cache(maxsize=16)
def _frame_plan(config: RadarConfig, chain: ChainConfig) -> _FramePlan:
    rs = _range_slice(config, chain)
    cfar = chain.cfar
    n_ch = config.n_virtual
    fp = footprint(cfar)
    hr, hd = fp.shape[0] // 2, fp.shape[1] // 2
    n_sub = ((rs.stop - rs.start + 1) // 2) * ((config.n_loops + 1) // 2)
    return _FramePlan(rs=rs, alpha=os_cfar_alpha(cfar.n_train, cfar.rank, cfar.pfa, n_ch),
                      prescreen_factor=10.0 ** (-chain.prescreen_db / 10.0),
                      floor_factor=10.0 ** (-chain.dynamic_range_db / 10.0),
                      noise_scale=os_cfar_noise_scale(cfar.n_train, cfar.rank, n_ch),
                      q_index=int(cfar.rank_fraction * (n_sub - 1)), hr=hr, hd=hd)


def point_cloud_of_cube(
    cube: NDArray, config: RadarConfig, chain: ChainConfig | None = None
) -> tuple[tuple[NDArray, NDArray, NDArray, NDArray], int]:
    """Detections of one frame.

    cube : (n_samples, n_loops, n_virtual) complex.
    Returns ``(range_m, omega_rad, doppler_mps, snr_db)``, each (K,) float,
    and the frame's :class:`~mmsnap_graph.data.results.Status` (``OK``,
    ``NON_FINITE_SAMPLES``, ``ALL_ZERO_CUBE`` or ``SATURATED``).
    """
    chain = _default_chain() if chain is None else chain
    x = check_cube(cube, config)
    return _point_cloud(x, config, chain, _frame_plan(config, chain))


def _point_cloud(x: NDArray, config: RadarConfig, chain: ChainConfig, plan: _FramePlan):
    """:func:`point_cloud_of_cube` of a checked cube, with its plan."""
    status, energy = _frame_status(x, chain)
    if status != Status.OK:
        return _empty_cloud_arrays(), status
    spec, power = range_doppler(x, config, range_window=chain.range_window,
                                doppler_window=chain.doppler_window,
                                clutter_removal=chain.clutter_removal, range_bins=plan.rs)
    # Cells below the float32 processing floor are rounding residue (of a
    # removed static return, for instance), not signal.
    floor = energy * plan.floor_factor
    if chain.cfar_method == "full":
        rows, cols, z = _detect_full(power, floor, config, chain)
    else:
        rows, cols, z = _detect_cells(power, floor, config, chain, plan)
    if rows.size == 0:
        return _empty_cloud_arrays(), status
    return _measure(spec, power, rows, cols, z, config, chain, plan), status


def _detect_full(power, floor, config: RadarConfig, chain: ChainConfig):
    """Detections by the whole-map OS-CFAR (the reference): local maxima
    (3 x 3, Doppler periodic) that pass, outside the clutter notch."""
    detected, z_map = os_cfar_2d(power, chain.cfar, config.n_virtual)
    peaks = power >= ndimage.maximum_filter(power, size=3, mode="wrap")
    if chain.clutter_removal:
        peaks[:, 0] = False  # the clutter notch
    rows, cols = np.nonzero(detected & peaks & (power > floor))
    return rows, cols, z_map[rows, cols]


def _detect_cells(power, floor, config: RadarConfig, chain: ChainConfig, plan: _FramePlan):
    """Detections by OS-CFAR at the pre-screened local maxima (module
    docstring): the same as :func:`_detect_full` at those cells."""
    # Pre-screen: above the threshold that the map's own rank statistic
    # would give, lowered by prescreen_db, and above the floor.
    sub = power[::2, ::2].ravel()
    q = np.partition(sub, plan.q_index)[plan.q_index]
    level = max(plan.alpha * float(q) * plan.prescreen_factor, floor)
    cand = power > level
    if chain.clutter_removal:
        cand[:, 0] = False  # the clutter notch
    if not cand.any():
        return np.zeros(0, np.intp), np.zeros(0, np.intp), np.zeros(0, power.dtype)
    # 3 x 3 local maxima (Doppler periodic, range reflected as in the padded
    # map): the cell is at least the maximum of its 3 x 3 block, taken as
    # two 3-cell maxima (Doppler, then range) of slices of the padded map.
    padded = pad_map(power, chain.cfar)
    nr, nd = power.shape
    if plan.hr and plan.hd:
        block = padded[plan.hr - 1:plan.hr + nr + 1, plan.hd - 1:plan.hd + nd + 1]
    else:  # no CFAR padding on one axis: pad by one cell for this test
        block = np.pad(np.pad(power, ((0, 0), (1, 1)), mode="wrap"), ((1, 1), (0, 0)),
                       mode="symmetric")
    m = np.maximum(np.maximum(block[:, :-2], block[:, 1:-1]), block[:, 2:])
    m = np.maximum(np.maximum(m[:-2], m[1:-1]), m[2:])
    rows, cols = np.nonzero(cand & (power >= m))
    keep, z = os_cfar_detections(power, rows, cols, chain.cfar, config.n_virtual,
                                 padded=padded)
    return rows[keep], cols[keep], z


def _measure(spec, power, rows, cols, z, config: RadarConfig, chain: ChainConfig,
             plan: _FramePlan):
    """Range, spatial frequency, Doppler and SNR of the detected cells."""
    # Sub-bin refinement on log power: the cell, its range neighbours
    # (clamped at the ends) and its Doppler neighbours (periodic).
    nr, nd = power.shape
    r_idx = np.stack([rows, np.maximum(rows - 1, 0), np.minimum(rows + 1, nr - 1), rows, rows])
    c_idx = np.stack([cols, cols, cols, (cols - 1) % nd, (cols + 1) % nd])
    cell = power[rows, cols]
    lp = np.log(np.maximum(power[r_idx, c_idx], np.finfo(np.float32).tiny).astype(float))
    off = parabolic_offset(lp[[1, 3]], lp[[0, 0]], lp[[2, 4]])  # (range, Doppler)
    range_m = (rows + plan.rs.start + off[0]) * config.range_resolution_m
    doppler = doppler_of_bin(cols + off[1], config)
    noise = z / plan.noise_scale
    with np.errstate(divide="ignore"):
        snr_db = 10.0 * np.log10(cell / np.maximum(noise, np.finfo(np.float32).tiny))
    omega, doppler = _angle_and_doppler(spec[rows, cols, :], doppler, snr_db, config, chain)
    return (range_m.astype(float), omega.astype(float), doppler.astype(float),
            snr_db.astype(float))


def _angle_and_doppler(snapshots, doppler, snr_db, config: RadarConfig, chain: ChainConfig):
    """Spatial frequency and (de-aliased) Doppler of the detected cells:
    de-aliasing only where ``snr_db >= chain.dealias_min_snr_db`` (one batch
    of angle FFTs for all cells and hypotheses)."""
    strong = snr_db >= chain.dealias_min_snr_db
    if chain.doppler_wraps and np.any(strong):
        omega, _, doppler = estimate_omega_dealiased(
            snapshots, doppler, config, max_wraps=int(chain.doppler_wraps),
            angle_window=chain.angle_window, n_fft=int(chain.angle_fft_size), dealias=strong)
        return omega, doppler
    omega, _ = estimate_omega(snapshots, doppler, config, angle_window=chain.angle_window,
                              n_fft=int(chain.angle_fft_size))
    return omega, doppler


def detect_frame(
    cube: NDArray, config: RadarConfig, chain: ChainConfig | None = None, *, frame: int = 0
) -> tuple[Detections, int]:
    """One frame's point cloud as :class:`Detections` (all rows ``frame``)
    and its :class:`~mmsnap_graph.data.results.Status` (see :func:`point_cloud_of_cube`)."""
    (r, w, v, s), status = point_cloud_of_cube(cube, config, chain)
    return Detections(frame=np.full(r.size, int(frame), dtype=np.int64), range_m=r,
                      omega_rad=w, doppler_mps=v, snr_db=s), status


def process_cubes(
    cubes: NDArray | Iterable[NDArray],
    config: RadarConfig,
    chain: ChainConfig | None = None,
    *,
    frames: NDArray | None = None,
    progress: bool = False,
    desc: str = "chain",
) -> ChainResult:
    """Point clouds and torso centroids of a sequence of frames.

    cubes : (F, n_samples, n_loops, n_virtual) complex (e.g. an h5py dataset
        or memory map: frames are read one at a time), or an iterable of
        per-frame cubes (then ``frames`` is required for F).
    frames : (F,) int frame numbers (default ``0..F-1``).
    progress : show a tqdm bar.
    """
    chain = ChainConfig() if chain is None else chain
    if not isinstance(config, RadarConfig):
        raise ConfigurationError(f"config must be a RadarConfig, got {type(config).__name__}")
    if hasattr(cubes, "shape"):
        shape = tuple(cubes.shape)
        if len(shape) != 4 or shape[1:] != config.cube_shape:
            raise ConfigurationError(
                f"cube shape {shape} disagrees with its radar configuration: expected "
                f"(F, {', '.join(map(str, config.cube_shape))})")
        n = shape[0]
        frame_iter = (cubes[i] for i in range(n))
    else:
        if frames is None:
            raise ValidationError("frames is required when cubes is an iterable")
        n = len(frames)
        frame_iter = iter(cubes)
    frames = np.arange(n) if frames is None else np.asarray(frames)
    if frames.shape != (n,) or (n and not np.issubdtype(frames.dtype, np.integer)):
        raise ValidationError(f"frames must be ({n},) int, got {frames.dtype} {frames.shape}")
    from tqdm.auto import tqdm  # deferred: only long runs need it

    cols: list[list[NDArray]] = [[], [], [], [], []]
    status = np.zeros(n, dtype=np.int64)
    plan = _frame_plan(config, chain)
    bar = tqdm(total=n, desc=desc, disable=not progress, unit="frame", leave=False)
    try:
        for i, cube in enumerate(frame_iter):
            if i >= n:
                break
            (r, w, v, s), st = _point_cloud(check_cube(cube, config), config, chain, plan)
            status[i] = st
            cols[0].append(np.full(r.size, frames[i], dtype=np.int64))
            for j, arr in enumerate((r, w, v, s)):
                cols[j + 1].append(arr)
            bar.update(1)
    finally:
        bar.close()
    if n == 0 or not cols[0]:
        cloud = Detections.empty()
    else:
        cat = [np.concatenate(c) for c in cols]
        cloud = Detections(frame=cat[0], range_m=cat[1], omega_rad=cat[2], doppler_mps=cat[3],
                           snr_db=cat[4])
    centroids = torso_centroids(cloud, chain.cluster,
                                doppler_resolution_mps=config.doppler_resolution_mps)
    bad = np.flatnonzero(status != Status.OK)
    if bad.size:
        kinds = sorted({Status(int(status[i])).message for i in bad})
        message = (f"{bad.size} of {n} frames gave no detections ({', '.join(kinds)}); "
                   f"first: frame {int(frames[bad[0]])}")
    else:
        message = f"{n} frames processed"
    return ChainResult(point_cloud=cloud, centroids=centroids, frame=frames, status=status,
                       success=bad.size == 0, message=message,
                       doppler_near_limit=doppler_near_limit(cloud.doppler_mps, config, chain))
