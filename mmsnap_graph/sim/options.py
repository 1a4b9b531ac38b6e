"""Options of the simulator (docs/SIMULATOR.md): the level models and
:class:`SimulationOptions`, which :func:`~mmsnap_graph.sim.simulate_recording`
and ``mmsnap simulate`` both build."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .._validation import check_count
from ..data.noise import MeasurementNoise
from ..data.radar_config import TABLE_I, RadarConfig
from ..errors import ConfigurationError, ValidationError
from .body import HumanBody
from .trajectories import RandomWalkOptions
from .networks import DEFAULT_FOV_RAD, DEFAULT_MAX_RANGE_M, DEFAULT_MIN_RANGE_M
from .real.physics import RealPhysics

__all__ = ["LEVELS", "DEFAULT_LEVELS", "CENTROID_NOISE", "PointCloudModel", "CubeModel",
           "SimulationOptions", "CLEAN"]

LEVELS = ("centroids", "point_cloud", "cube")
#: Levels simulated unless asked otherwise: raw cubes are large (Table I:
#: 5.9 MB per node and frame), so they are only made on request.
DEFAULT_LEVELS = ("centroids", "point_cloud")

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


@dataclass(frozen=True, kw_only=True, slots=True)
class SimulationOptions:
    """How to simulate (what to simulate, levels, length and seed, are
    arguments of :func:`~mmsnap_graph.sim.simulate_recording`).

    physics : :class:`~mmsnap_graph.sim.real.physics.RealPhysics` (default: the
        knobs measured on real TI recordings) applied to the centroid and
        point-cloud levels; None: the clean model (a point target with
        independent Gaussian centroid errors and a whole body in every
        radar's view), whose statistics the estimators' own tests use.
    radar : chirp configuration of every node (Table I by default).
    frame_period_s : frame period (default the radar's, 150 ms).
    n_targets : walkers (each with its own trajectory).
    fov_rad, max_range_m, min_range_m : visibility limits of every level.
    centroid_noise : sigmas of the clean centroid level (with physics only
        its Doppler sigma is used: range and angle errors come from the
        physics).
    centroid_p_miss : probability that a target in view has no centroid.
    point_cloud_model, cube_model, body : level models.
    cube_frames : frames that get a raw cube: None = all, an int N = the
        first N, or a sequence of frame numbers.
    known_poses : store each node's true pose as its ``pose`` (else None;
        the true poses are always in ``truth.node_poses``).
    trajectory_options : how the ``"random"`` trajectory walks (a
        :class:`~mmsnap_graph.sim.trajectories.RandomWalkOptions`; None = its
        defaults; not for the ``"straight"`` kind).
    """

    physics: RealPhysics | None = RealPhysics()
    radar: RadarConfig = TABLE_I
    frame_period_s: float | None = None
    n_targets: int = 1
    fov_rad: float = DEFAULT_FOV_RAD
    max_range_m: float = DEFAULT_MAX_RANGE_M
    min_range_m: float = DEFAULT_MIN_RANGE_M
    centroid_noise: MeasurementNoise = CENTROID_NOISE
    centroid_p_miss: float = 0.0
    point_cloud_model: PointCloudModel = PointCloudModel()
    cube_model: CubeModel = CubeModel()
    body: HumanBody = HumanBody()
    cube_frames: Any = None
    known_poses: bool = False
    trajectory_options: RandomWalkOptions | None = None

    def __post_init__(self) -> None:
        for name, cls in (("physics", RealPhysics), ("radar", RadarConfig),
                          ("centroid_noise", MeasurementNoise),
                          ("point_cloud_model", PointCloudModel), ("cube_model", CubeModel),
                          ("body", HumanBody)):
            v = getattr(self, name)
            if not isinstance(v, cls) and not (name == "physics" and v is None):
                raise ConfigurationError(f"SimulationOptions.{name} must be a {cls.__name__}"
                                         f"{' or None' if name == 'physics' else ''}, "
                                         f"got {type(v).__name__}")
        if self.frame_period_s is not None:
            fp = self.frame_period_s
            if not (isinstance(fp, (int, float)) and np.isfinite(fp) and 0 < fp <= 10):
                raise ValidationError(f"SimulationOptions.frame_period_s={fp!r} must be in "
                                      "(0, 10] seconds (milliseconds given?)")
        check_count(self.n_targets, "SimulationOptions.n_targets")
        if not (np.isfinite(self.fov_rad) and 0 < self.fov_rad <= np.pi / 2):
            raise ValidationError(f"SimulationOptions.fov_rad={self.fov_rad!r} must be in "
                                  "(0, pi/2] radians (degrees given?)")
        if not (np.isfinite(self.min_range_m) and 0 <= self.min_range_m < self.max_range_m):
            raise ValidationError("SimulationOptions ranges must satisfy 0 <= min_range_m < "
                                  f"max_range_m, got {self.min_range_m!r}, {self.max_range_m!r}")
        if not 0 <= self.centroid_p_miss < 1:
            raise ValidationError(f"SimulationOptions.centroid_p_miss={self.centroid_p_miss!r} "
                                  "must be in [0, 1)")
        if self.cube_frames is not None and np.ndim(self.cube_frames) == 1:
            object.__setattr__(self, "cube_frames", tuple(int(v) for v in self.cube_frames))
        if (self.trajectory_options is not None
                and not isinstance(self.trajectory_options, RandomWalkOptions)):
            raise ValidationError("SimulationOptions.trajectory_options must be a "
                                  "RandomWalkOptions or None, got "
                                  f"{type(self.trajectory_options).__name__}")

    @property
    def clean(self) -> bool:
        """True for the clean model (no physics)."""
        return self.physics is None


#: The clean model: a point target with independent Gaussian centroid errors.
CLEAN = SimulationOptions(physics=None)
