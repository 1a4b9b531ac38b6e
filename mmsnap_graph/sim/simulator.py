"""Simulated recordings of walking humans seen by a radar network
(docs/SIMULATOR.md).

:func:`simulate_recording` builds a :class:`~mmsnap_graph.data.recording.Recording`
with its :class:`~mmsnap_graph.data.recording.Truth` (torso states of every target
and the true node poses) and any of three levels per node:

- ``"centroids"``: one row per target per frame in view: the torso's
  measurement :func:`factors.models.measurement_model` plus Gaussian noise
  (:data:`CENTROID_NOISE` by default), optional missed detections
  (``centroid_p_miss``);
- ``"point_cloud"``: one detection per resolvable body scatterer (torso,
  arms, legs: limb micro-Doppler), detected with a probability from its SNR,
  with SNR-dependent noise, plus false alarms (:class:`PointCloudModel`); a
  statistical model of the FFT + CFAR chain, not the chain itself;
- ``"cube"``: raw ADC cubes synthesized by :mod:`mmsnap_graph.sim.cube` from
  the body scatterers, thermal noise and static clutter (:class:`CubeModel`).

Random streams are derived from ``seed`` per purpose and per node, so adding
or removing a level leaves the other levels unchanged.
"""

from __future__ import annotations

import dataclasses
import os
import tempfile
from dataclasses import dataclass
from typing import Iterable, Mapping, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray
from tqdm import tqdm

from factors.models import global_to_local, measurement_model, wrap_angle

from ..errors import ConfigurationError, ValidationError
from ..data.noise import MeasurementNoise
from ..data.radar_config import TABLE_I, RadarConfig
from ..data.recording import Detections, NodeData, Recording, Truth
from .._validation import as_float_array, check_count, check_finite
from .body import BodyScatterers, HumanBody, body_scatterers
from .cube import post_fft_snr_db, scatterer_amplitude, synthesize_cubes
from .networks import (
    DEFAULT_FOV_RAD,
    DEFAULT_MAX_RANGE_M,
    DEFAULT_MIN_RANGE_M,
    common_area,
    in_field_of_view,
    network_poses,
)
from .trajectories import DEFAULT_N_FRAMES, TRAJECTORY_KINDS, make_trajectory

__all__ = ["LEVELS", "CENTROID_NOISE", "PointCloudModel", "CubeModel", "simulate_recording",
           "simulate_targets"]

LEVELS = ("centroids", "point_cloud", "cube")

# Stream identifiers for the derived random generators.
_TRAJECTORY, _BODY, _CENTROIDS, _POINT_CLOUD, _CUBE, _CLUTTER = range(6)


def _stream(seed: int, purpose: int, index: int = 0) -> np.random.Generator:
    return np.random.default_rng([int(seed), purpose, index])


#: Noise of the centroid level, one row per target per frame (a
#: :class:`~mmsnap_graph.data.noise.MeasurementNoise`). These are the errors of
#: a torso-cluster centroid, not the radar's resolutions (the paper's 0.035 m,
#: pi/4 rad, 0.1807 m/s are the resolutions, used by the fusion as
#: conservative sigmas):
#:
#: - range 0.05 m: the centroid of points spread over the torso's depth
#:   (about 0.2 m) with 3.5 cm range cells;
#: - spatial frequency 0.08 rad: about 1.5 deg at broadside
#:   (``d omega = pi cos(theta) d theta``), the scatter of an interpolated
#:   8-element-array angle estimate of a 0.4 m wide torso at a few metres;
#: - Doppler 0.1 m/s: the torso's Doppler centroid, perturbed by limb points
#:   that leak into the torso cluster (Doppler cell 0.18 m/s).
CENTROID_NOISE = MeasurementNoise(range_m=0.05, omega_rad=0.08, doppler_mps=0.10)


@dataclass(frozen=True, kw_only=True, slots=True)
class PointCloudModel:
    """Statistical model of the detections of the FFT + OS-CFAR chain.

    SNR of a scatterer after the range, Doppler and angle FFTs: the cube
    module's radar equation (:func:`mmsnap_graph.sim.cube.scatterer_amplitude`,
    per channel after the 2D FFT) plus ``10 log10(n_virtual)`` of coherent
    angle gain. Detection probability (Swerling 1, square-law detector,
    threshold set for ``p_false_alarm``): ``Pd = p_false_alarm ** (1 / (1 + snr))``,
    times ``1 - p_miss``.

    Scatterers of one target that fall in the same (range, Doppler, angle)
    cell (``angle_fft_size`` bins over ``[-pi, pi)``) merge into one
    detection, the strongest. Each detection's error is Gaussian with
    variance ``bin**2 / 12 + resolution**2 / (2 snr)`` per coordinate
    (bin quantization plus thermal noise), the Doppler aliased into
    ``[-max_doppler, max_doppler)``; its ``snr_db`` is the true SNR plus
    ``snr_std_db`` of noise.

    False alarms: ``false_alarms_per_frame`` (Poisson mean) per node and
    frame, uniform in range ``[min_range, max_range]``, in spatial frequency
    over the field of view, and in Doppler over the unambiguous interval,
    with an SNR just above the threshold (threshold + exponential of mean
    1.5 dB); their ``target_id`` is -1.
    """

    p_false_alarm: float = 1e-4
    p_miss: float = 0.0
    false_alarms_per_frame: float = 1.0
    angle_fft_size: int = 64
    snr_std_db: float = 1.0
    noise_std: float = 1.0

    def __post_init__(self) -> None:
        if not 0 < self.p_false_alarm < 1:
            raise ValidationError(f"p_false_alarm={self.p_false_alarm!r} must be in (0, 1)")
        if not 0 <= self.p_miss < 1:
            raise ValidationError(f"p_miss={self.p_miss!r} must be in [0, 1)")
        if not (np.isfinite(self.false_alarms_per_frame) and self.false_alarms_per_frame >= 0):
            raise ValidationError(f"false_alarms_per_frame={self.false_alarms_per_frame!r} "
                                  "must be finite and >= 0")
        check_count(self.angle_fft_size, "angle_fft_size", 2)
        if not (np.isfinite(self.snr_std_db) and self.snr_std_db >= 0):
            raise ValidationError(f"snr_std_db={self.snr_std_db!r} must be finite and >= 0")
        if not (np.isfinite(self.noise_std) and self.noise_std > 0):
            raise ValidationError(f"noise_std={self.noise_std!r} must be finite and > 0")

    @property
    def threshold_db(self) -> float:
        """Detection threshold over the noise, ``10 log10(-ln p_false_alarm)``."""
        return float(10 * np.log10(-np.log(self.p_false_alarm)))


@dataclass(frozen=True, kw_only=True, slots=True)
class CubeModel:
    """Raw-ADC level: thermal noise and static clutter.

    noise_std : complex noise std per ADC sample (the scatterers' amplitudes
    follow the radar equation relative to it, :mod:`mmsnap_graph.sim.cube`).
    n_clutter : static scatterers per node (walls, poles, furniture), placed
    uniformly in the node's field of view between ``clutter_min_range_m``
    and ``clutter_max_range_m`` with RCS log-uniform in ``clutter_rcs_m2``;
    fixed for the whole recording.
    quantize : round I and Q to whole ADC counts and clip them to int16, as
    a capture holds them (then ``noise_std`` is in counts; use 8 or more).
    Integer-valued cubes also compress several times better.
    """

    noise_std: float = 1.0
    quantize: bool = False
    n_clutter: int = 8
    clutter_rcs_m2: tuple[float, float] = (1.0, 20.0)
    clutter_min_range_m: float = 2.0
    clutter_max_range_m: float = 15.0

    def __post_init__(self) -> None:
        if not (np.isfinite(self.noise_std) and self.noise_std >= 0):
            raise ValidationError(f"noise_std={self.noise_std!r} must be finite and >= 0")
        check_count(self.n_clutter, "n_clutter", 0)
        lo, hi = self.clutter_rcs_m2
        if not (0 < lo <= hi):
            raise ValidationError(f"clutter_rcs_m2={self.clutter_rcs_m2!r} must be 0 < lo <= hi")
        if not (0 < self.clutter_min_range_m < self.clutter_max_range_m):
            raise ValidationError("clutter ranges must satisfy 0 < clutter_min_range_m < "
                                  f"clutter_max_range_m, got {self.clutter_min_range_m!r}, "
                                  f"{self.clutter_max_range_m!r}")


# --------------------------------------------------------------------------
def simulate_targets(network: str | Mapping[str, ArrayLike], trajectory: str | ArrayLike = "straight",
                     *, n_targets: int = 1, n_frames: int = DEFAULT_N_FRAMES,
                     frame_period_s: float = TABLE_I.frame_period_s, seed: int = 0,
                     **trajectory_options) -> NDArray:
    """Torso states ``(n_targets, F, 4)`` of the targets, global frame.

    ``trajectory`` is a kind (``"straight"``, ``"random"``; each target gets
    its own random stream) or explicit states ``(F, 4)`` or
    ``(n_targets, F, 4)`` (then ``n_targets`` and ``n_frames`` follow them).
    """
    if isinstance(trajectory, str):
        if trajectory not in TRAJECTORY_KINDS:
            raise ValidationError(f"trajectory={trajectory!r} must be one of "
                                  f"{TRAJECTORY_KINDS} or an array of states")
        check_count(n_targets, "n_targets")
        area = common_area(network)
        return np.stack([make_trajectory(trajectory, area, n_frames=n_frames,
                                         frame_period_s=frame_period_s,
                                         rng=_stream(seed, _TRAJECTORY, t), **trajectory_options)
                         for t in range(int(n_targets))])
    states = check_finite(as_float_array(trajectory, "trajectory"), "trajectory")
    if states.ndim == 2:
        states = states[None]
    if states.ndim != 3 or states.shape[2] != 4 or states.shape[1] < 1:
        raise ValidationError(f"trajectory states must have shape (F, 4) or (n_targets, F, 4), "
                              f"got {np.shape(trajectory)}")
    return states


def _in_view(points, pose, limits) -> NDArray:
    return in_field_of_view(points, pose, **limits)


def _centroids(states: NDArray, pose: NDArray, noise: MeasurementNoise, p_miss: float, limits,
               rng: np.random.Generator, snr_db: NDArray) -> Detections:
    n_t, n_f, _ = states.shape
    h, _ = measurement_model(states, pose)                                   # (T, F, 3)
    visible = _in_view(states[..., :2], pose, limits)
    z = h + rng.standard_normal(h.shape) * noise.sigmas
    keep = visible & (rng.random(visible.shape) >= p_miss)
    tid, frame = np.nonzero(keep)
    order = np.lexsort((tid, frame))
    tid, frame = tid[order], frame[order]
    zz = z[tid, frame]
    return Detections(frame=frame, range_m=np.abs(zz[:, 0]), omega_rad=wrap_angle(zz[:, 1]),
                      doppler_mps=zz[:, 2], snr_db=snr_db[tid, frame], target_id=tid)


def _detection_snr_db(radar: RadarConfig, rcs_m2: NDArray, range_m: NDArray,
                      noise_std: float) -> NDArray:
    amp = scatterer_amplitude(radar, rcs_m2, np.maximum(range_m, 1e-3), noise_std=noise_std)
    return post_fft_snr_db(radar, amp, noise_std) + 10 * np.log10(radar.n_virtual)


def _point_cloud(bodies: Sequence[BodyScatterers], pose: NDArray, radar: RadarConfig,
                 model: PointCloudModel, limits, rng: np.random.Generator) -> Detections:
    n_f = bodies[0].positions_m.shape[0]
    rows = []
    for tid, b in enumerate(bodies):
        m = b.positions_m.shape[1]
        st = np.concatenate([b.positions_m, b.velocities_mps], axis=-1)     # (F, M, 4)
        h, _ = measurement_model(st, pose)                                   # (F, M, 3)
        # Scatterers without RCS (e.g. a body with limbs switched off) reflect nothing.
        vis = _in_view(b.positions_m, pose, limits) & (b.rcs_m2 > 0)[None, :]
        snr = _detection_snr_db(radar, np.broadcast_to(b.rcs_m2, (n_f, m)), h[..., 0],
                                model.noise_std)
        f_idx, m_idx = np.nonzero(vis)
        rows.append((np.full(f_idx.size, tid), f_idx, h[f_idx, m_idx], snr[f_idx, m_idx]))
    tid = np.concatenate([r[0] for r in rows])
    frame = np.concatenate([r[1] for r in rows])
    h = np.concatenate([r[2] for r in rows])
    snr = np.concatenate([r[3] for r in rows])
    # Merge scatterers of one target in one (range, Doppler, angle) cell.
    d_r, d_v = radar.range_resolution_m, radar.doppler_resolution_mps
    d_w = 2 * np.pi / model.angle_fft_size
    keys = np.stack([frame, tid, np.floor(h[:, 0] / d_r), np.floor(h[:, 2] / d_v),
                     np.floor(h[:, 1] / d_w)], axis=1).astype(np.int64)
    strongest = np.argsort(-snr, kind="stable")
    _, first = np.unique(keys[strongest], axis=0, return_index=True)
    sel = strongest[first]
    tid, frame, h, snr = tid[sel], frame[sel], h[sel], snr[sel]
    # Detection (Swerling 1): Pd = Pfa ** (1 / (1 + snr)).
    snr_lin = 10 ** (snr / 10)
    pd = model.p_false_alarm ** (1 / (1 + snr_lin)) * (1 - model.p_miss)
    hit = rng.random(pd.shape) < pd
    tid, frame, h, snr, snr_lin = tid[hit], frame[hit], h[hit], snr[hit], snr_lin[hit]
    res = np.array([d_r, radar.omega_resolution_rad, d_v])
    bins = np.array([d_r, d_w, d_v])
    sigma = np.sqrt(bins ** 2 / 12 + res ** 2 / (2 * snr_lin[:, None]))
    z = h + sigma * rng.standard_normal(h.shape)
    v_max = radar.max_doppler_mps
    z[:, 2] = (z[:, 2] + v_max) % (2 * v_max) - v_max
    z[:, 1] = wrap_angle(z[:, 1])
    z[:, 0] = np.abs(z[:, 0])
    snr_meas = snr + model.snr_std_db * rng.standard_normal(snr.shape)
    # False alarms.
    n_fa = rng.poisson(model.false_alarms_per_frame, n_f)
    fa_frame = np.repeat(np.arange(n_f), n_fa)
    k = fa_frame.size
    w_max = np.pi * np.sin(limits["fov_rad"])
    fa = np.stack([rng.uniform(limits["min_range_m"], limits["max_range_m"], k),
                   rng.uniform(-w_max, w_max, k), rng.uniform(-v_max, v_max, k)], axis=1)
    fa_snr = model.threshold_db + rng.exponential(1.5, k)
    frame = np.concatenate([frame, fa_frame])
    z = np.concatenate([z, fa])
    snr_all = np.concatenate([snr_meas, fa_snr])
    tid = np.concatenate([tid, np.full(k, -1)])
    order = np.argsort(frame, kind="stable")
    return Detections(frame=frame[order], range_m=z[order, 0], omega_rad=z[order, 1],
                      doppler_mps=z[order, 2], snr_db=snr_all[order], target_id=tid[order])


def _clutter(radar: RadarConfig, model: CubeModel, limits, rng: np.random.Generator):
    n = int(model.n_clutter)
    if n == 0:
        return None
    r = rng.uniform(model.clutter_min_range_m, min(model.clutter_max_range_m,
                                                   0.95 * radar.max_range_m), n)
    theta = rng.uniform(-limits["fov_rad"], limits["fov_rad"], n)
    lo, hi = model.clutter_rcs_m2
    rcs = np.exp(rng.uniform(np.log(lo), np.log(hi), n))
    amp = scatterer_amplitude(radar, rcs, r, noise_std=max(model.noise_std, 1e-12))
    phase = np.exp(2j * np.pi * rng.random(n))
    return np.stack([r * np.sin(theta), r * np.cos(theta)], axis=1), amp * phase


def _cube_inputs(bodies: Sequence[BodyScatterers], pose: NDArray, radar: RadarConfig,
                 model: CubeModel, frames: NDArray, limits):
    pos_l, vel_l, amp_l = [], [], []
    c, s = np.cos(pose[2]), np.sin(pose[2])
    rot = np.array([[c, s], [-s, c]])                     # global -> local rotation
    noise_ref = max(model.noise_std, 1e-12)
    for f in frames:
        p = np.concatenate([b.positions_m[f] for b in bodies])
        v = np.concatenate([b.velocities_mps[f] for b in bodies])
        rcs = np.concatenate([b.rcs_m2 for b in bodies])
        vis = _in_view(p, pose, limits) & (rcs > 0)
        pl = global_to_local(p[vis], pose)
        vl = v[vis] @ rot.T
        r = np.hypot(pl[:, 0], pl[:, 1])
        # The carrier phase 4 pi R / lambda of each scatterer, folded into the
        # complex amplitude with the sign sim.cube's Doppler term implies
        # (exp(+j 4 pi R / lambda)), so the phase stays coherent across frames.
        amp = (scatterer_amplitude(radar, rcs[vis], r, noise_std=noise_ref)
               * np.exp(4j * np.pi * r / radar.wavelength_m))
        pos_l.append(pl)
        vel_l.append(vl)
        amp_l.append(amp)
    return pos_l, vel_l, amp_l


def _cubes(bodies, pose, radar, model, frames, limits, rng, clutter_rng, progress_bar,
           memmap_dir, node_name) -> NDArray:
    clutter = _clutter(radar, model, limits, clutter_rng)
    shape = (frames.size, *radar.cube_shape)
    if memmap_dir is not None:
        fd, tmp = tempfile.mkstemp(prefix=f"cube_{node_name}_", suffix=".c64", dir=memmap_dir)
        os.close(fd)
        out = np.memmap(tmp, dtype=np.complex64, mode="w+", shape=shape)
    else:
        out = np.empty(shape, dtype=np.complex64)
    chunk = 8
    for start in range(0, frames.size, chunk):
        sl = slice(start, min(start + chunk, frames.size))
        pos, vel, amp = _cube_inputs(bodies, pose, radar, model, frames[sl], limits)
        block = out[sl]
        synthesize_cubes(radar, pos, vel, amp, rng=rng, noise_std=model.noise_std,
                         clutter=clutter, out=block)
        if model.quantize:
            view = block.view(np.float32)
            np.round(view, out=view)
            np.clip(view, -32768, 32767, out=view)
        if progress_bar is not None:
            progress_bar.update(sl.stop - sl.start)
    return out


def _check_inputs(levels, radar, centroid_noise, centroid_p_miss) -> tuple[str, ...]:
    levels = tuple(levels)
    bad = [lv for lv in levels if lv not in LEVELS]
    if bad or not levels:
        raise ValidationError(f"levels={levels!r} must be a non-empty subset of {LEVELS}")
    if not isinstance(radar, RadarConfig):
        raise ConfigurationError(f"radar must be a RadarConfig, got {type(radar).__name__}")
    if not isinstance(centroid_noise, MeasurementNoise):
        raise ConfigurationError(f"centroid_noise must be a MeasurementNoise, "
                                 f"got {type(centroid_noise).__name__}")
    if not 0 <= centroid_p_miss < 1:
        raise ValidationError(f"centroid_p_miss={centroid_p_miss!r} must be in [0, 1)")
    return levels


def _cube_frame_numbers(cube_frames, n_f: int) -> NDArray:
    """The frames that get a raw cube (see :func:`simulate_recording`)."""
    if cube_frames is None:
        return np.arange(n_f)
    if np.ndim(cube_frames) == 0:
        check_count(cube_frames, "cube_frames", 0, n_f)
        return np.arange(int(cube_frames))
    frames_c = np.asarray(cube_frames)
    if (frames_c.ndim != 1 or not np.issubdtype(frames_c.dtype, np.integer)
            or np.any(frames_c < 0) or np.any(frames_c >= n_f)):
        raise ValidationError(f"cube_frames must be frame numbers in [0, {n_f}), "
                              f"got {cube_frames!r}")
    return frames_c


@dataclass(frozen=True, slots=True)
class _Setup:
    """Everything a node's simulation needs besides its pose and index."""

    levels: tuple
    radar: RadarConfig
    states: NDArray
    bodies: list
    limits: dict
    seed: int
    centroid_noise: MeasurementNoise
    centroid_p_miss: float
    point_cloud_model: PointCloudModel
    cube_model: CubeModel
    torso_rcs_m2: float
    frames_c: NDArray
    known_poses: bool
    cube_memmap_dir: object


def _simulate_node(setup: _Setup, i: int, name: str, pose: NDArray, bar) -> NodeData:
    """One node's levels, each from its own random stream."""
    radar, states, seed = setup.radar, setup.states, setup.seed
    n_t, n_f, _ = states.shape
    kw = {"name": name, "radar": radar, "pose": pose if setup.known_poses else None}
    if "centroids" in setup.levels:
        torso_snr = np.stack([
            _detection_snr_db(radar, np.full(n_f, setup.torso_rcs_m2),
                              measurement_model(states[t], pose)[0][:, 0],
                              setup.point_cloud_model.noise_std) for t in range(n_t)])
        kw["centroids"] = _centroids(states, pose, setup.centroid_noise, setup.centroid_p_miss,
                                     setup.limits, _stream(seed, _CENTROIDS, i), torso_snr)
    if "point_cloud" in setup.levels:
        kw["point_cloud"] = _point_cloud(setup.bodies, pose, radar, setup.point_cloud_model,
                                         setup.limits, _stream(seed, _POINT_CLOUD, i))
    if "cube" in setup.levels:
        kw["cube"] = _cubes(setup.bodies, pose, radar, setup.cube_model, setup.frames_c,
                            setup.limits, _stream(seed, _CUBE, i), _stream(seed, _CLUTTER, i),
                            bar, setup.cube_memmap_dir, name)
        kw["cube_frame"] = setup.frames_c
    return NodeData(**kw)


def _metadata(network, trajectory, setup: _Setup) -> dict:
    return {
        "generator": "mmsnap_graph.sim.simulate_recording",
        "network": network if isinstance(network, str) else "custom",
        "trajectory": trajectory if isinstance(trajectory, str) else "given",
        "seed": int(setup.seed),
        "n_targets": int(setup.states.shape[0]),
        "levels": ",".join(setup.levels),
        "fov_rad": setup.limits["fov_rad"],
        "max_range_m": setup.limits["max_range_m"],
        "min_range_m": setup.limits["min_range_m"],
        "centroid_range_std_m": setup.centroid_noise.range_m,
        "centroid_omega_std_rad": setup.centroid_noise.omega_rad,
        "centroid_doppler_std_mps": setup.centroid_noise.doppler_mps,
    }


def simulate_recording(
    network: str | Mapping[str, ArrayLike] = "C",
    trajectory: str | ArrayLike = "straight",
    *,
    levels: Iterable[str] = LEVELS,
    n_frames: int = DEFAULT_N_FRAMES,
    frame_period_s: float | None = None,
    seed: int = 0,
    radar: RadarConfig = TABLE_I,
    n_targets: int = 1,
    fov_rad: float = DEFAULT_FOV_RAD,
    max_range_m: float = DEFAULT_MAX_RANGE_M,
    min_range_m: float = DEFAULT_MIN_RANGE_M,
    centroid_noise: MeasurementNoise = CENTROID_NOISE,
    centroid_p_miss: float = 0.0,
    point_cloud_model: PointCloudModel = PointCloudModel(),
    cube_model: CubeModel = CubeModel(),
    cube_frames: int | ArrayLike | None = None,
    body: HumanBody = HumanBody(),
    known_poses: bool = False,
    progress: bool = False,
    cube_memmap_dir: str | os.PathLike | None = None,
    trajectory_options: Mapping | None = None,
) -> Recording:
    """Simulate a recording of ``n_targets`` walking humans.

    network : ``"A"``, ``"B"``, ``"C"`` or a mapping ``name -> (3,) pose``
        (first = reference S1).
    trajectory : ``"straight"``, ``"random"`` or states ``(F, 4)`` /
        ``(n_targets, F, 4)`` (global frame, torso).
    levels : any of ``"centroids"``, ``"point_cloud"``, ``"cube"``.
    n_frames, frame_period_s : length and frame period (default the radar's,
        150 ms; 600 frames = 90 s).
    seed : all randomness derives from it (per purpose and node).
    radar : chirp configuration of every node (Table I by default).
    fov_rad, max_range_m, min_range_m : visibility limits of every level.
    centroid_noise : sigmas of the centroid level (default :data:`CENTROID_NOISE`).
    centroid_p_miss : probability that a target in view has no centroid.
    point_cloud_model, cube_model, body : level models.
    cube_frames : frames that get a raw cube: None = all, an int N = the
        first N, or an array of frame numbers.
    known_poses : store each node's true pose as its ``pose`` (else None; the
        true poses are always in ``truth.node_poses``).
    progress : show a tqdm bar over the cube synthesis.
    cube_memmap_dir : if given, cubes are built in memory-mapped files in that
        folder (for long cube recordings); the caller deletes the files.
    Returns the :class:`Recording` with truth and metadata.
    """
    levels = _check_inputs(levels, radar, centroid_noise, centroid_p_miss)
    if frame_period_s is None:
        frame_period_s = radar.frame_period_s
    elif frame_period_s != radar.frame_period_s:
        radar = dataclasses.replace(radar, frame_period_s=float(frame_period_s))
    poses = network_poses(network)
    states = simulate_targets(network, trajectory, n_targets=n_targets, n_frames=n_frames,
                              frame_period_s=frame_period_s, seed=seed,
                              **dict(trajectory_options or {}))
    n_t, n_f, _ = states.shape
    setup = _Setup(
        levels=levels, radar=radar, states=states,
        bodies=[body_scatterers(states[t], frame_period_s, body=body, rng=_stream(seed, _BODY, t))
                for t in range(n_t)],
        limits=dict(fov_rad=float(fov_rad), max_range_m=float(max_range_m),
                    min_range_m=float(min_range_m)),
        seed=seed, centroid_noise=centroid_noise, centroid_p_miss=float(centroid_p_miss),
        point_cloud_model=point_cloud_model, cube_model=cube_model,
        torso_rcs_m2=body.torso_rcs_m2, frames_c=_cube_frame_numbers(cube_frames, n_f),
        known_poses=known_poses, cube_memmap_dir=cube_memmap_dir)
    bar = None
    if "cube" in levels and progress:
        bar = tqdm(total=len(poses) * setup.frames_c.size, unit="frame", desc="raw ADC cubes")
    try:
        nodes = {name: _simulate_node(setup, i, name, pose, bar)
                 for i, (name, pose) in enumerate(poses.items())}
    finally:
        if bar is not None:
            bar.close()
    truth = Truth(frame=np.tile(np.arange(n_f), n_t), target_id=np.repeat(np.arange(n_t), n_f),
                  state=states.reshape(n_t * n_f, 4), node_poses=poses)
    return Recording(frame_period_s=frame_period_s, nodes=nodes, truth=truth,
                     metadata=_metadata(network, trajectory, setup))
