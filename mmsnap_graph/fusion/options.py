"""The options of one-shot fusion, validated once: :class:`RobustOptions`
(the robust fit), :class:`FusionOptions` (how to solve and what to
return) and :class:`NetworkCalibration` (the network's calibration: poses,
their covariances, clock offsets, range offset), taken by
:func:`~mmsnap_graph.fusion.solve.solve`, :func:`~mmsnap_graph.fusion.solve.robust_solve`,
:func:`~mmsnap_graph.fusion.recording.sequence.fuse_recording` and
:class:`~mmsnap_graph.fusion.stream.frame_stream.FrameStream`. GTSAM-free.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import MappingProxyType
from typing import Literal, Mapping

import numpy as np

from .._validation import as_float_array, check_count, check_finite, check_probability
from ..errors import ValidationError
from .robust import RESIDUAL_GATE_PROBABILITY, check_robust, check_robust_k, residual_gate_threshold
from .solvers.settings import LM_SETTINGS, SOLVERS, LevenbergMarquardtSettings, check_solver

__all__ = ["RobustOptions", "FusionOptions", "DEFAULT_OPTIONS", "robust_options",
           "NetworkCalibration"]


def _positive(value: object, name: str) -> float:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.floating)) \
            or not (math.isfinite(value) and value > 0):
        raise ValidationError(f"{name} must be a positive finite number, got {value!r}")
    return float(value)


@dataclass(frozen=True, kw_only=True, slots=True)
class RobustOptions:
    """Robust one-shot fusion (:mod:`mmsnap_graph.fusion.robust`,
    docs/ROBUST.md).

    kernel : ``"gate"`` (refit without the node whose whitened residual fails
        the chi-square gate), ``"huber"`` or ``"cauchy"`` (GTSAM's
        m-estimators per node).
    k : the kernel constant (None: :data:`factors.robust.ROBUST_K_DEFAULT`
        of the kernel); not taken by ``"gate"``.
    gate_probability : the probability ``p`` of the per-node residual gate,
        ``chi2.ppf(p, 3)`` (default :data:`~mmsnap_graph.fusion.robust.RESIDUAL_GATE_PROBABILITY`).

    A plain string is shorthand for the kernel with the defaults
    (:func:`robust_options`): ``robust="gate"`` is
    ``RobustOptions(kernel="gate")``.
    """

    kernel: Literal["gate", "huber", "cauchy"]
    k: float | None = None
    gate_probability: float = RESIDUAL_GATE_PROBABILITY

    def __post_init__(self) -> None:
        if check_robust(self.kernel) is None:
            raise ValidationError("kernel must be 'gate', 'huber' or 'cauchy', got None "
                                  "(pass robust=None for plain least squares)")
        if self.kernel == "gate":
            if self.k is not None:
                raise ValidationError(f"k is the constant of a kernel; kernel='gate' takes "
                                      f"none, got k={self.k!r}")
        else:
            if self.k is not None and (isinstance(self.k, (bool, np.bool_)) or not isinstance(
                    self.k, (int, float, np.integer, np.floating))):
                raise ValidationError(f"k must be a number, got {self.k!r}")
            if self.k is not None and not (math.isfinite(self.k) and self.k > 0):
                raise ValidationError(f"k must be finite and > 0, got {self.k!r}")
            object.__setattr__(self, "k", check_robust_k(self.kernel, self.k))
        object.__setattr__(self, "gate_probability",
                           check_probability(self.gate_probability, "gate_probability"))

    @property
    def threshold(self) -> float:
        """The per-node gate ``chi2.ppf(gate_probability, 3)``."""
        return residual_gate_threshold(self.gate_probability)

    @property
    def kernel_pair(self) -> tuple[str, float] | None:
        """``(name, k)`` of a kernel, None for the gate."""
        return None if self.kernel == "gate" else (self.kernel, self.k)


def robust_options(robust: object) -> RobustOptions | None:
    """``robust`` as :class:`RobustOptions`: None stays None, a kernel name
    gets the defaults; ValidationError for anything else."""
    if robust is None or isinstance(robust, RobustOptions):
        return robust
    if isinstance(robust, str):
        return RobustOptions(kernel=robust)
    raise ValidationError(
        f"robust must be None, 'gate', 'huber', 'cauchy' or a RobustOptions, got {robust!r}")


@dataclass(frozen=True, kw_only=True, slots=True)
class FusionOptions:
    """How one-shot fusion solves and what it returns
    (:func:`~mmsnap_graph.fusion.solve.solve`); every combination is valid
    for every solver and every driver.

    solver : ``"gtsam"`` (the reference), ``"vectorized"`` (the default) or
        ``"scalar"`` (:data:`~mmsnap_graph.fusion.solvers.settings.SOLVERS`).
    lm : :class:`~mmsnap_graph.fusion.solvers.settings.LevenbergMarquardtSettings`
        the damping and stopping rules (``lm.max_iterations``: reaching it
        is a failure).

    covariance : ``"laplace"`` (the inverse Gauss-Newton information, what
        ``gtsam.Marginals`` returns) or ``"grid"`` (also the paper's numerical
        posterior covariance on a 4D grid, every solver).
    grid_points_per_axis, grid_half_width_sigmas : the grid's layout
        (:func:`mmsnap_graph.fusion.grid.grid_posterior`).

    The vectorized solver's:

    step_tolerance : a frame converges when a step is below this, relative
        to ``1 + |state|``.
    newton_after : steps after which a frame adds the second-order residual
        term (Newton's quadratic convergence near a weakly observed minimum).
    chunk_size : frames solved together in the first stage.

    A recording's (the rest of a recording's fusion is
    :class:`~mmsnap_graph.fusion.config.FusionConfig`'s):

    block_rows : rows fused per solve.
    """

    lm: LevenbergMarquardtSettings = LM_SETTINGS
    covariance: Literal["laplace", "grid"] = "laplace"
    grid_points_per_axis: int = 21
    grid_half_width_sigmas: float = 5.0
    step_tolerance: float = 1e-10
    newton_after: int = 10
    chunk_size: int = 8192
    solver: Literal["gtsam", "vectorized", "scalar"] = "vectorized"
    block_rows: int = 65536

    def __post_init__(self) -> None:
        if not isinstance(self.lm, LevenbergMarquardtSettings):
            raise ValidationError(f"lm must be a LevenbergMarquardtSettings, got {self.lm!r}")
        if self.covariance not in ("laplace", "grid"):
            raise ValidationError(f"covariance must be 'laplace' or 'grid', got "
                                  f"{self.covariance!r}")
        check_solver(self.solver, SOLVERS)
        for name in ("grid_points_per_axis", "newton_after", "chunk_size", "block_rows"):
            object.__setattr__(self, name, check_count(getattr(self, name), name))
        for name in ("grid_half_width_sigmas", "step_tolerance"):
            object.__setattr__(self, name, _positive(getattr(self, name), name))


#: The default options.
DEFAULT_OPTIONS = FusionOptions()


def check_options(options: object) -> FusionOptions:
    """``options`` if it is a :class:`FusionOptions`; ValidationError otherwise."""
    if not isinstance(options, FusionOptions):
        raise ValidationError(f"options must be a FusionOptions, got {type(options).__name__}")
    return options


def _by_node(value: object, field: str, what: str) -> Mapping | None:
    """``value`` as a read-only ``{node name: value}`` copy (None stays None)."""
    if value is None:
        return None
    if not isinstance(value, Mapping):
        raise ValidationError(f"NetworkCalibration.{field} must be a mapping node name -> "
                              f"{what}, got {type(value).__name__}")
    return MappingProxyType(dict(value))


@dataclass(frozen=True, kw_only=True, slots=True)
class NetworkCalibration:
    """What a calibration of the network gives fusion (every part optional).

    node_poses : name -> ``(x_m, y_m, phi_rad)`` (None: the poses stored in
        the recording).
    pose_covariances : name -> (3, 3) covariance of the pose in the Pose2
        body tangent (calibration-aware fusion, docs/CONVENTIONS.md); a node
        left out has an exact pose (None: every pose exact).
    time_offset_s : name -> the node's clock offset in seconds (node time +
        offset = reference time); a node left out keeps its clock.
    range_offset_m : the range offset (reflection depth, metres) added to
        every centroid range before fusion (None: none).

    Each mapping is copied, read-only; poses and offsets are checked here
    (shape, finite), the covariances against the recording's nodes by
    :func:`~mmsnap_graph.fusion.recording.sequence.fuse_recording`.
    """

    node_poses: Mapping[str, np.ndarray] | None = None
    pose_covariances: Mapping[str, np.ndarray] | None = None
    time_offset_s: Mapping[str, float] | None = None
    range_offset_m: float | None = None

    def __post_init__(self) -> None:
        poses = _by_node(self.node_poses, "node_poses", "(x_m, y_m, phi_rad)")
        if poses is not None:
            checked = {}
            for name, pose in poses.items():
                arr = check_finite(as_float_array(pose, f"pose of {name}"), f"pose of {name}")
                if arr.shape != (3,):
                    raise ValidationError(f"pose of {name} must have shape (3,), got {arr.shape}")
                arr = arr.copy()
                arr.flags.writeable = False
                checked[name] = arr
            poses = MappingProxyType(checked)
        object.__setattr__(self, "node_poses", poses)
        object.__setattr__(self, "pose_covariances", _by_node(
            self.pose_covariances, "pose_covariances", "(3, 3) covariance"))
        offsets = _by_node(self.time_offset_s, "time_offset_s", "seconds")
        if offsets is not None:
            for name, tau in offsets.items():
                if isinstance(tau, (bool, np.bool_)) or not isinstance(
                        tau, (int, float, np.integer, np.floating)) or not math.isfinite(tau):
                    raise ValidationError(f"NetworkCalibration.time_offset_s[{name!r}]={tau!r} "
                                          "must be a finite number of seconds")
        object.__setattr__(self, "time_offset_s", offsets)
        if self.range_offset_m is not None:
            d = self.range_offset_m
            if isinstance(d, (bool, np.bool_)) or not isinstance(
                    d, (int, float, np.integer, np.floating)) or not (math.isfinite(d)
                                                                     and abs(d) <= 1.0):
                raise ValidationError(f"NetworkCalibration.range_offset_m={d!r} must be finite "
                                      "metres within +-1 m (millimetres given?)")
