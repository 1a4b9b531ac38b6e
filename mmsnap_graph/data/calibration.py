"""The result records of self-calibration, shared by the estimators and the files.

- :class:`PairwiseCalibration`: the pose of one node in another's frame
  from matched tracks (paper eqs. 11-14), the edges of a network;
- :class:`RecordingCalibration`: every node's pose in the reference's frame,
  with a :class:`~mmsnap_graph.data.calibration_facts.CalibrationStatus`
  and the typed facts of :mod:`.calibration_facts`. The pose graph
  (:func:`mmsnap_graph.calibration.pose_graph_calibration`) and the whole
  chain (:func:`mmsnap_graph.calibration.calibrate_recording`) both return
  it; :mod:`mmsnap_graph.io.calibration` stores and reads it.

Covariances are in the Pose2 body tangent ``(dx_b, dy_b, dphi)``
(docs/CONVENTIONS.md, "Pose2 and covariance frames").
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping, TypeVar

import numpy as np
from numpy.typing import NDArray

from .._validation import as_float_array, check_finite, check_shape
from ..errors import ValidationError
from .calibration_facts import CalibrationFact, CalibrationStatus, LagEvidence
from .noise import NoiseEstimate

__all__ = ["PairwiseCalibration", "RecordingCalibration", "CALIBRATION_METHODS"]

#: ``RecordingCalibration.method``: the step whose poses it holds ("" when a
#: file does not say).
CALIBRATION_METHODS = ("pose_graph", "joint", "")

F = TypeVar("F", bound=CalibrationFact)


@dataclass(frozen=True, kw_only=True, slots=True)
class PairwiseCalibration:
    """Pose of node ``node_b`` in node ``node_a``'s frame (``a_T_b``) from
    matched tracks: the closed form's result and a network's edge.

    pose : (3,) ``(x_m, y_m, phi_rad)``; covariance : (3, 3) in the body
        tangent of ``pose``. With ``success`` both are finite and the
        covariance positive definite (checked here).
    rmse_m : ``sqrt(J_min / K)`` (paper eq. 14); cost_m2 : ``J_min`` (m^2);
        n_frames : K, the matched frames used.
    lag_frames : ``node_b``'s frame ``k + lag`` matches ``node_a``'s ``k``.
    track_a, track_b : matched track ids (``-1``: several, or not known).
    frames : (K,) int, ``node_a``'s frame numbers; points_a_m, points_b_m :
        (K, 2) the matched points in each node's frame (a network solve
        reuses them); None when not kept (e.g. read from a file).
    autocorrelation_factor : ``tau`` the covariance was multiplied by for
        residuals correlated in time (1.0: frames independent).
    success, message : as scipy.optimize results (the closed form's).
    lag_evidence : how the track matching decided a nonzero lag (None when
        lag 0 won outright or no lag was searched).
    lag_ambiguous : the lag is not determined and ``covariance`` covers the
        poses of the competing lags.
    """

    node_a: str = "a"
    node_b: str = "b"
    pose: NDArray
    covariance: NDArray
    rmse_m: float = float("nan")
    cost_m2: float = float("nan")
    n_frames: int = 0
    lag_frames: int = 0
    track_a: int = -1
    track_b: int = -1
    frames: NDArray | None = None
    points_a_m: NDArray | None = None
    points_b_m: NDArray | None = None
    autocorrelation_factor: float = 1.0
    success: bool = True
    message: str = ""
    lag_evidence: LagEvidence | None = None
    lag_ambiguous: bool = False

    def __post_init__(self) -> None:
        if self.node_a == self.node_b:
            raise ValidationError(f"an edge must join two nodes, got {self.node_a!r} twice")
        name = f"edge {self.node_a}-{self.node_b}"
        pose = check_shape(as_float_array(self.pose, f"{name} pose"), (3,), f"{name} pose")
        cov = check_shape(as_float_array(self.covariance, f"{name} covariance"), (3, 3),
                          f"{name} covariance")
        if self.success:
            check_finite(pose, f"{name} pose")
            cov = 0.5 * (check_finite(cov, f"{name} covariance") + cov.T)
            try:
                np.linalg.cholesky(cov)
            except np.linalg.LinAlgError:
                raise ValidationError(f"{name} covariance must be positive definite, got "
                                      f"eigenvalues {np.linalg.eigvalsh(cov)}") from None
        object.__setattr__(self, "pose", pose)
        object.__setattr__(self, "covariance", cov)
        if self.lag_evidence is not None and not isinstance(self.lag_evidence, LagEvidence):
            raise ValidationError(f"{name} lag_evidence must be a LagEvidence or None, got "
                                  f"{self.lag_evidence!r}")
        self._check_points(name)

    def _check_points(self, name: str) -> None:
        if self.points_a_m is None and self.points_b_m is None:
            return
        if self.points_a_m is None or self.points_b_m is None:
            raise ValidationError(f"{name}: points_a_m and points_b_m go together")
        a = check_finite(check_shape(as_float_array(self.points_a_m, f"{name} points_a_m"),
                                     (None, 2), f"{name} points_a_m"), f"{name} points_a_m")
        b = check_finite(check_shape(as_float_array(self.points_b_m, f"{name} points_b_m"),
                                     a.shape, f"{name} points_b_m"), f"{name} points_b_m")
        object.__setattr__(self, "points_a_m", a)
        object.__setattr__(self, "points_b_m", b)
        if self.frames is not None:
            fr = np.asarray(self.frames)
            if fr.shape != (a.shape[0],) or not np.issubdtype(fr.dtype, np.integer):
                raise ValidationError(f"{name} frames must be ({a.shape[0]},) integers, got "
                                      f"{fr.dtype} {fr.shape}")
            object.__setattr__(self, "frames", fr.astype(np.int64))

    @property
    def has_points(self) -> bool:
        """True when the matched points are kept (a network solve uses them)."""
        return self.points_a_m is not None


@dataclass(frozen=True, kw_only=True, slots=True)
class RecordingCalibration:
    """Every node's calibrated pose in the reference's frame.

    reference : the node at ``(0, 0, 0)``; node_names : every node, in order.
    poses, covariances, lag_frames : per calibrated node (``(3,)``,
        ``(3, 3)`` body tangent, whole frames: the node's frame ``k + lag``
        is the reference's ``k``).
    unreachable : nodes with no path of matched tracks to the reference.
    edges : the pairwise estimates (:class:`PairwiseCalibration`).
    method : ``"joint"`` when the joint graph refined the poses,
        ``"pose_graph"`` when they are the pose graph's ("" from a file that
        does not say). source : ``"tracks"`` or ``"centroids"`` ("" when not
        known).
    status : :class:`CalibrationStatus` (``OK``: :attr:`success`).
    facts : what the steps found or could not determine
        (:mod:`mmsnap_graph.data.calibration_facts`), in the order found.
    failures : node or pair ``"a-b"`` -> why it could not be used, in the
        estimators' words.
    noise : every node's noise estimated from the data at the calibrated
        poses (None when read from a file: :mod:`mmsnap_graph.io.noise`).
    time_offset_s : name -> clock offset in seconds (node time + offset =
        reference time; 0 for the reference); time_offset_variances : its
        variance (s^2; NaN where not estimated).
    range_offset_m, range_offset_variance : the estimated range offset
        (reflection depth, m) and its variance (m^2); NaN when not
        estimated. ``mmsnap fuse`` adds it to every centroid range.
    joint_covariance : (3M, 3M) covariance of the M non-reference poses in
        ``joint_order``, their cross-covariances included (the poses share
        the target's states, so their errors are correlated); None when not
        computed or read from a file.
    model_covariances : name -> (3, 3) the estimator's own covariances
        before any widening (the joint graph's marginals; the pose graph's
        covariances): ``covariances`` adds what the model leaves out (errors
        correlated in time, a reflection depth, lags not determined; the
        ``PoseCovariance`` and ``LagNotDetermined`` facts); empty when read
        from a file.
    """

    reference: str
    node_names: tuple[str, ...]
    poses: Mapping[str, NDArray]
    covariances: Mapping[str, NDArray]
    lag_frames: Mapping[str, int]
    unreachable: tuple[str, ...] = ()
    edges: tuple[PairwiseCalibration, ...] = ()
    method: str = ""
    source: str = ""
    status: CalibrationStatus = CalibrationStatus.OK
    facts: tuple[CalibrationFact, ...] = ()
    failures: Mapping[str, str] = field(default_factory=dict)
    noise: NoiseEstimate | None = None
    time_offset_s: Mapping[str, float] = field(default_factory=dict)
    time_offset_variances: Mapping[str, float] = field(default_factory=dict)
    range_offset_m: float = float("nan")
    range_offset_variance: float = float("nan")
    joint_covariance: NDArray | None = None
    joint_order: tuple[str, ...] = ()
    model_covariances: Mapping[str, NDArray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "status", CalibrationStatus(self.status))
        for name in ("node_names", "unreachable", "edges", "facts", "joint_order"):
            object.__setattr__(self, name, tuple(getattr(self, name)))
        if self.method not in CALIBRATION_METHODS:
            raise ValidationError(f"method={self.method!r} must be one of "
                                  f"{list(CALIBRATION_METHODS)}")
        bad = [f for f in self.facts if not isinstance(f, CalibrationFact)]
        if bad:
            raise ValidationError(f"facts must be CalibrationFact records, got {bad[0]!r}")
        bad = [e for e in self.edges if not isinstance(e, PairwiseCalibration)]
        if bad:
            raise ValidationError(f"edges must be PairwiseCalibration records, got {bad[0]!r}")
        if self.noise is not None and not isinstance(self.noise, NoiseEstimate):
            raise ValidationError(f"noise must be a NoiseEstimate or None, got {self.noise!r}")

    @property
    def success(self) -> bool:
        """``status is CalibrationStatus.OK``."""
        return self.status is CalibrationStatus.OK

    @property
    def message(self) -> str:
        """The status's one-line message (the facts say the rest)."""
        return self.status.message

    def facts_of(self, kind: type[F]) -> tuple[F, ...]:
        """The facts of one class, in order."""
        return tuple(f for f in self.facts if isinstance(f, kind))

    def fact(self, kind: type[F]) -> F | None:
        """The first fact of one class, or None."""
        found = self.facts_of(kind)
        return found[0] if found else None
