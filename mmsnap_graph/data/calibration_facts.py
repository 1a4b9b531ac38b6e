"""What a calibration reports: one status and typed facts.

:class:`CalibrationStatus` says whether a calibration (of a network,
:class:`~mmsnap_graph.data.calibration.RecordingCalibration`, or of the joint
graph, ``JointCalibration``) is usable and, if not, why; its message comes
from one table. The facts say what the steps found or could not determine,
each as a frozen record with its numbers in SI units (frames where a lag is
meant). Nothing here is worded for a person: ``mmsnap calibrate`` words the
facts (:func:`mmsnap_graph.app.commands.calibrate.fact_text`); the
calibration JSON stores them as ``{"kind": ..., <fields>}`` objects
(docs/FORMAT.md).

Every fact class has a ``kind`` (its JSON name) and only fields of the types
below, which its constructor coerces (a JSON list becomes a tuple, ``null`` a
NaN float): ``str``, ``int``, ``float``, ``bool``, :class:`CalibrationStatus`
and tuples of these. A new fact is a class here and a line in :data:`FACTS`.
"""

# No ``from __future__ import annotations``: the constructors coerce by the
# fields' real types (typing.get_type_hints), not by their names.
import dataclasses
import enum
import math
import numbers
import typing
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ..errors import ValidationError

__all__ = [
    "CalibrationStatus",
    "CalibrationFact",
    "PoseGraphFit",
    "JointFit",
    "RobustPassFailed",
    "PoseCovariance",
    "RangeOffsetEstimated",
    "PoseNotObservable",
    "SolveBrokeDown",
    "TargetsAssociated",
    "JointNoise",
    "ClockOffsetsTried",
    "JointSkipped",
    "JointRejected",
    "LagEvidence",
    "LagNotDetermined",
    "LagsDisputed",
    "NoiseNotIdentified",
    "WindowsCombined",
    "FACTS",
    "FACT_KINDS",
    "NOISE_COMPONENTS",
]

#: The three measurement components, in ``MeasurementNoise.sigmas`` order.
NOISE_COMPONENTS = ("range", "omega", "doppler")


class CalibrationStatus(enum.IntEnum):
    """Why a calibration is not usable, or ``OK`` (its :attr:`message`
    from one table, as scipy's ``OptimizeResult``).

    The JSON and the ``/calibration`` group store the lower-case name
    (``"ok"``, ``"nodes_unreachable"``, ...); :meth:`from_name` reads it.
    """

    OK = 0
    NODES_UNREACHABLE = 1
    NOT_OBSERVABLE = 2
    SOLVE_FAILED = 3

    @property
    def message(self) -> str:
        """A one-line description of the status."""
        return _MESSAGES[self]

    @property
    def label(self) -> str:
        """The lower-case name the files store."""
        return self.name.lower()

    @classmethod
    def from_name(cls, name: str) -> "CalibrationStatus":
        """The status whose :attr:`label` (or name) is ``name``."""
        try:
            return cls[str(name).upper()]
        except KeyError:
            raise ValidationError(f"status {name!r} must be one of "
                                  f"{[s.label for s in cls]}") from None


_MESSAGES = {
    CalibrationStatus.OK: "every node with a path to the reference calibrated",
    CalibrationStatus.NODES_UNREACHABLE: "some nodes are not calibrated: no matched track or "
                                         "common frames link them to the reference",
    CalibrationStatus.NOT_OBSERVABLE: "a pose is not determined by the data along some "
                                      "direction (a target that hardly moves?)",
    CalibrationStatus.SOLVE_FAILED: "the solve broke down (singular or non-finite numbers)",
}


class CalibrationFact:
    """Base of the facts: coerces the fields to their declared types and
    checks the declared choices (``_choices``: field -> allowed values)."""

    __slots__ = ()
    kind: ClassVar[str] = ""
    _choices: ClassVar[dict] = {}

    def __post_init__(self) -> None:
        hints = _hints(type(self))
        for f in dataclasses.fields(self):
            where = f"{self.kind}.{f.name}"
            value = _coerce(getattr(self, f.name), hints[f.name], where)
            allowed = self._choices.get(f.name)
            if allowed is not None and value not in allowed:
                raise ValidationError(f"{where}={value!r} must be one of {list(allowed)}")
            object.__setattr__(self, f.name, value)


_HINTS: dict[type, dict] = {}


def _hints(cls: type) -> dict:
    if cls not in _HINTS:
        _HINTS[cls] = typing.get_type_hints(cls)
    return _HINTS[cls]


def _coerce(value, tp, where: str):
    """``value`` as type ``tp`` (module doc), or ValidationError naming ``where``."""
    if typing.get_origin(tp) is tuple:
        args = typing.get_args(tp)
        if not isinstance(value, (tuple, list, np.ndarray)):
            raise ValidationError(f"{where} must be a sequence, got {value!r}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_coerce(v, args[0], f"{where}[{i}]") for i, v in enumerate(value))
        if len(value) != len(args):
            raise ValidationError(f"{where} must hold {len(args)} values, got {value!r}")
        return tuple(_coerce(v, t, f"{where}[{i}]") for i, (v, t) in enumerate(zip(value, args)))
    if tp is CalibrationStatus:
        return value if isinstance(value, CalibrationStatus) else (
            CalibrationStatus.from_name(value) if isinstance(value, str)
            else CalibrationStatus(_coerce(value, int, where)))
    if tp is bool:
        if not isinstance(value, (bool, np.bool_)):
            raise ValidationError(f"{where} must be true or false, got {value!r}")
        return bool(value)
    if tp is str:
        if not isinstance(value, str):
            raise ValidationError(f"{where} must be a string, got {value!r}")
        return value
    if value is None and tp is float:
        return math.nan
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise ValidationError(f"{where} must be a number, got {value!r}")
    if tp is float:
        try:
            return float(value)
        except OverflowError:  # an integer beyond the float range
            return math.inf if value > 0 else -math.inf
    if isinstance(value, numbers.Integral):
        return int(value)
    if not (math.isfinite(value) and float(value).is_integer()):
        raise ValidationError(f"{where} must be an integer, got {value!r}")
    return int(value)


_fact = dataclass(frozen=True, kw_only=True, slots=True)


@_fact
class PoseGraphFit(CalibrationFact):
    """The pose graph of the pairwise estimates was solved: ``solve``
    ``"points"`` (every pose at once from the edges' matched points) or
    ``"edges"`` (between factors of the pairwise poses); ``n_nodes`` nodes
    from ``n_edges`` edges; ``final_error`` half the sum of squared whitened
    residuals; ``autocorrelation_factor`` the points solve's covariance
    factor for residuals correlated in time (1 for ``"edges"``)."""

    kind: ClassVar[str] = "pose_graph_fit"
    _choices: ClassVar[dict] = {"solve": ("points", "edges")}
    solve: str
    n_nodes: int
    n_edges: int
    iterations: int = 0
    final_error: float = math.nan
    autocorrelation_factor: float = 1.0


@_fact
class JointFit(CalibrationFact):
    """The joint graph was solved: ``n_nodes`` nodes on ``n_frames`` frames,
    ``n_outliers`` detections flagged as outliers; the numpy pre-solve's
    steps per pass (``presolve_steps``, empty when it did not run) and
    whether it converged; ``iterations`` GTSAM's steps after it; ``turns``
    motion factors left out as sharp turns."""

    kind: ClassVar[str] = "joint_fit"
    n_nodes: int
    n_frames: int
    n_outliers: int = 0
    iterations: int = 0
    presolve_steps: tuple[int, ...] = ()
    presolve_converged: bool = True
    turns: int = 0


@_fact
class RobustPassFailed(CalibrationFact):
    """The joint graph's robust pass ended with ``status``; the result is
    the pass with Gaussian factors on the same (associated) detections."""

    kind: ClassVar[str] = "robust_pass_failed"
    status: CalibrationStatus


@_fact
class PoseCovariance(CalibrationFact):
    """How the pose covariances were computed. ``method``: ``"marginals"``
    (the graph's marginals), ``"long_run"`` (widened where the frames'
    errors are correlated in time or the model is not exact: over
    ``bandwidth_frames`` frames, variances up to ``max_widening`` times the
    marginals'; 1.0: within the marginals' sampling noise, so they are
    kept) or ``"schur"`` (the elimination failed: a dense Schur complement).
    ``reflection_depth_rms_m`` : a reflection depth not estimated whose
    effect on the poses is in the covariance (0: none);
    ``without_depth_nodes`` and ``without_depth_sigmas`` (three per node:
    ``x_b`` m, ``y_b`` m, ``phi`` rad) : each node's 1-sigma without that
    term, what sessions of one walker or a recording's halves scatter by
    (the depth is common to them). ``depth_data_sigma_m`` : the depth's
    sigma from the data alone, how far the geometry separates it from the
    poses (0: not computed). ``failure`` : why a more careful method
    was not used ("" when none failed)."""

    kind: ClassVar[str] = "pose_covariance"
    _choices: ClassVar[dict] = {"method": ("marginals", "long_run", "schur")}
    method: str
    bandwidth_frames: int = 0
    max_widening: float = 1.0
    reflection_depth_rms_m: float = 0.0
    failure: str = ""
    without_depth_nodes: tuple[str, ...] = ()
    without_depth_sigmas: tuple[float, ...] = ()
    depth_data_sigma_m: float = 0.0


@_fact
class RangeOffsetEstimated(CalibrationFact):
    """A range offset common to every node (the body's reflection depth)
    was estimated: ``offset_m`` with variance ``variance_m2``, from the
    prior ``prior_mean_m`` +- ``prior_sigma_m``."""

    kind: ClassVar[str] = "range_offset_estimated"
    offset_m: float
    variance_m2: float
    prior_mean_m: float
    prior_sigma_m: float


@_fact
class PoseNotObservable(CalibrationFact):
    """``node``'s pose is not determined along ``directions`` (unit vectors
    in its body tangent ``(dx_b, dy_b, dphi)``)."""

    kind: ClassVar[str] = "pose_not_observable"
    node: str
    directions: tuple[tuple[float, float, float], ...]


@_fact
class SolveBrokeDown(CalibrationFact):
    """A solve of ``step`` (``"pose_graph"`` or ``"joint"``) broke down;
    ``reason`` is the numerical library's or the estimator's own words."""

    kind: ClassVar[str] = "solve_broke_down"
    _choices: ClassVar[dict] = {"step": ("pose_graph", "joint")}
    step: str
    reason: str


@_fact
class TargetsAssociated(CalibrationFact):
    """Several centroids per frame: they were associated across nodes into
    ``n_targets`` target tracks, ``n_states`` (frame, target) states."""

    kind: ClassVar[str] = "targets_associated"
    n_targets: int
    n_states: int


@_fact
class JointNoise(CalibrationFact):
    """The centroid noise the joint graph was weighted by: ``sigmas``
    ``(range_m, omega_rad, doppler_mps)`` from ``source`` (``"temporal"``:
    each node's own centroid sequence, pooled; ``"residuals"``: the joint
    graph's residuals; ``"given"``: the caller's); ``identified`` per
    component (False: the fallback's value, the closed form's track RMSE
    for omega or the paper's)."""

    kind: ClassVar[str] = "joint_noise"
    _choices: ClassVar[dict] = {"source": ("temporal", "residuals", "given")}
    sigmas: tuple[float, float, float]
    identified: tuple[bool, bool, bool]
    source: str


@_fact
class ClockOffsetsTried(CalibrationFact):
    """With several centroids per frame the clock offsets beyond the
    whole-frame lags were tried in one more joint solve. ``outcome``:
    ``"estimated"`` (kept), ``"beyond_half_frame"`` (a fraction beyond half a
    frame contradicts the lag search: whole-frame lags kept),
    ``"not_determined"`` (no fraction ``evidence_z`` sigmas from zero: kept
    whole), ``"no_start"`` (no successful joint solve to start from) or
    ``"solve_failed"`` (the timed solve ended with ``solve_status``).
    ``nodes``, ``fractions``, ``z`` : each node's fraction of a frame beyond
    its lag and its z (empty unless the timed solve succeeded)."""

    kind: ClassVar[str] = "clock_offsets_tried"
    _choices: ClassVar[dict] = {"outcome": ("estimated", "beyond_half_frame", "not_determined",
                                            "no_start", "solve_failed")}
    outcome: str
    nodes: tuple[str, ...] = ()
    fractions: tuple[float, ...] = ()
    z: tuple[float, ...] = ()
    evidence_z: float = math.nan
    solve_status: CalibrationStatus = CalibrationStatus.OK


@_fact
class JointSkipped(CalibrationFact):
    """The joint refinement did not run: no centroids of a common target
    could be associated across nodes (``association_error``: why the
    association failed, "" when it found nothing)."""

    kind: ClassVar[str] = "joint_skipped"
    association_error: str = ""


@_fact
class JointRejected(CalibrationFact):
    """The joint refinement ended with ``status``: the pose graph's poses
    were kept."""

    kind: ClassVar[str] = "joint_rejected"
    status: CalibrationStatus


@_fact
class LagEvidence(CalibrationFact):
    """How the track matching of ``node_a``-``node_b`` decided its best
    nonzero lag ``lag_frames`` against lag 0 on the same tracks (z-score
    ``z``, threshold ``evidence_z``). ``outcome``: ``"determined"`` (kept),
    ``"untested"`` (too few frames at both lags: kept), ``"not_determined"``
    (z below the threshold, or too few frames: lag 0 kept) or
    ``"window_edge"`` (at the edge of the +-``window_frames`` search window
    it does not beat its inner neighbour by the threshold: lag 0 kept)."""

    kind: ClassVar[str] = "lag_evidence"
    _choices: ClassVar[dict] = {"outcome": ("determined", "untested", "not_determined",
                                            "window_edge")}
    node_a: str = "a"
    node_b: str = "b"
    lag_frames: int
    outcome: str
    z: float = math.nan
    evidence_z: float = math.nan
    window_frames: int = 0

    @property
    def kept_lag_frames(self) -> int:
        """The lag the matching kept."""
        return self.lag_frames if self.outcome in ("determined", "untested") else 0


@_fact
class LagNotDetermined(CalibrationFact):
    """The lag of ``node_a``-``node_b`` is not determined (other lags fit
    about as well with other poses): the covariance covers their poses.
    ``tested``: the shifts within the matching's window were tested on the
    centroids the joint graph fitted and against its clock offset
    (``clock_fraction`` +- ``clock_sigma`` frames): ``rejected_shifts`` were
    rejected (z >= ``evidence_z``), ``kept_shifts`` not; untested: the
    covariance covers the track matching's spread of lags."""

    kind: ClassVar[str] = "lag_not_determined"
    node_a: str
    node_b: str
    tested: bool
    kept_shifts: tuple[int, ...] = ()
    rejected_shifts: tuple[int, ...] = ()
    clock_fraction: float = math.nan
    clock_sigma: float = math.nan
    evidence_z: float = math.nan


@_fact
class LagsDisputed(CalibrationFact):
    """The joint graph's clock offsets contradict the track matching's
    lags (``lags`` of ``nodes``: each offset ``fractions`` +- ``sigmas``
    frames beyond its lag, more than half a frame and ``evidence_z`` sigmas
    away): the calibration was made again with lag 0 (the nodes' own
    sync)."""

    kind: ClassVar[str] = "lags_disputed"
    nodes: tuple[str, ...]
    lags: tuple[int, ...]
    fractions: tuple[float, ...]
    sigmas: tuple[float, ...]
    evidence_z: float = math.nan


@_fact
class NoiseNotIdentified(CalibrationFact):
    """At the calibrated poses the data do not identify ``node``'s
    ``component`` sigma (one of :data:`NOISE_COMPONENTS`): ``sigma`` is the
    fallback's value; ``reason`` the estimator's words."""

    kind: ClassVar[str] = "noise_not_identified"
    _choices: ClassVar[dict] = {"component": NOISE_COMPONENTS}
    node: str
    component: str
    sigma: float
    reason: str = ""


@_fact
class WindowsCombined(CalibrationFact):
    """A long recording was calibrated window by window (bounded memory):
    ``n_windows`` windows of ``window_s`` seconds, ``n_combined`` of them
    combined in information form (the poses are static); ``skipped``: why
    each other window was left out (``"frames a-b: reason"``). The
    windows' spread about the combined poses, ``spread_chi2`` over
    ``spread_dof`` degrees of freedom, widened the covariance by
    ``spread_factor`` (1: consistent with their covariances). The facts
    that follow are the first combined window's."""

    kind: ClassVar[str] = "windows_combined"
    window_s: float
    n_windows: int
    n_combined: int
    skipped: tuple[str, ...] = ()
    spread_chi2: float = math.nan
    spread_dof: int = 0
    spread_factor: float = 1.0


#: Every fact class, in the order ``mmsnap calibrate`` lists them by default.
FACTS = (PoseGraphFit, TargetsAssociated, JointNoise, ClockOffsetsTried, JointFit,
         RobustPassFailed, PoseCovariance, RangeOffsetEstimated, PoseNotObservable,
         SolveBrokeDown, JointSkipped, JointRejected, LagEvidence, LagNotDetermined,
         LagsDisputed, NoiseNotIdentified, WindowsCombined)
#: ``kind`` -> fact class (the JSON reader's table).
FACT_KINDS = {cls.kind: cls for cls in FACTS}
