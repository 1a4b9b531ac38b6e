"""The settings of a joint calibration (:func:`~.solve.joint_calibration`),
checked once when the object is made.

The data of one solve (detections, reference, starting poses, measurement
noise, frame period, whole-frame lags) are arguments of the function; what
stays the same from one recording to the next (kernels, motion model, gates,
limits) is a :class:`JointOptions`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from factors.robust import ROBUST_K_DEFAULT

from ...errors import ValidationError
from ..._validation import check_count, check_positive, check_probability, frozen_vector
from ..pairwise.closed_form import DEFAULT_MIN_COMMON_FRAMES, DEFAULT_MIN_SPREAD_M
from .covariance import DEFAULT_BANDWIDTH_S

__all__ = ["DEFAULT_ROBUST_K", "DEFAULT_MOTION_ROBUST_K", "REFLECTION_DEPTH_RMS_M", "JointOptions"]

#: Default width of the robust kernels on the whitened 3-vector norm (GTSAM's
#: mEstimator ``k``): Huber 1.345, Cauchy 2.5; the project's one table,
#: :data:`factors.robust.ROBUST_K_DEFAULT`.
DEFAULT_ROBUST_K = ROBUST_K_DEFAULT
#: Default width of the Cauchy kernel on the motion factors' whitened
#: 4-vector norm (a Gaussian acceleration's norm is about 2; a sharp turn's
#: is 5-20): see docs/CALIBRATION.md, "Sharp turns".
DEFAULT_MOTION_ROBUST_K = 3.0

#: Root mean square of a walking person's reflection depth (the centroid
#: nearer to each radar than the body's centre): the physical prior 0.10 +-
#: 0.05 m, sqrt(0.10^2 + 0.05^2) (docs/CALIBRATION.md, "Extended targets").
REFLECTION_DEPTH_RMS_M = float(np.hypot(0.10, 0.05))

_KERNELS = (None, "huber", "cauchy")


def _flag(value, name: str) -> bool:
    if not isinstance(value, (bool, np.bool_)):
        raise ValidationError(f"{name} must be a bool, got {value!r}")
    return bool(value)


@dataclass(frozen=True, kw_only=True, slots=True)
class JointOptions:
    """How :func:`~mmsnap_graph.calibration.joint_calibration` solves.

    robust, robust_k : kernel against ghost detections (None: Gaussian).
        Default k (:data:`DEFAULT_ROBUST_K`): Huber 1.345, Cauchy 2.5 (on
        the whitened 3-vector norm).
    motion : add constant-velocity factors between consecutive frames no
        more than ``max_motion_gap_frames`` apart (the solve then needs
        ``frame_period_s``).
    sigma_a_mps2 : white-acceleration sigma of the motion factors.
    motion_robust, motion_robust_k : kernel on the motion factors' whitened
        4-vector norm in the robust pass (with ``robust`` set), so that a
        sharp turn bends the track instead of making its detections
        outliers; the motion factors it finds beyond the chi-square(4)
        gate of ``gate_probability`` (the turns) are left out of the
        final Gaussian pass. None: Gaussian motion factors throughout.
    time_offsets : estimate each non-reference node's clock offset jointly
        with the poses (docs/CALIBRATION.md, "Clock offsets"); the node's
        detection at frame ``k`` is of the state ``F(tau) x_k``.
    recentre_lags : with ``time_offsets``, solve again with a node's
        whole-frame lag moved one frame when its offset lies more than a
        quarter of a frame beyond it (docs/CALIBRATION.md, "Clock offsets").
        False: the lags given are kept and only the fraction is estimated
        (the several-centroid path: a move there is not checked against
        lag 0 on the same data, and gave synchronised real radars a 1-frame
        lag).
    state_prior_sigmas : (4,) sigmas of the zero-mean state prior (m, m,
        m/s, m/s).
    gate_probability : the probability of keeping a consistent detection:
        a detection whose whitened squared residual exceeds the chi-square(3)
        ``gate_probability`` quantile is an outlier (0.999: one consistent
        detection in 1,000 is flagged).
    min_common_frames : fewer frames seen by two nodes raise CalibrationError.
    min_spread_m : the robust start's closed forms need the target to move
        this far in each node.
    max_pose_variance : a pose marginal variance (m^2 or rad^2) above this
        means that the pose is not determined: ``success=False``.
    max_pose_condition : so does an eigenvalue of a pose covariance more
        than this times its smallest (a standing target leaves S2 free to
        turn about it: variances of 1e-6 against 0.2 in a test).
    max_iterations : GTSAM's iteration limit per pass.
    presolve : run the numpy pre-solve (:mod:`.presolve`, same models)
        before each GTSAM pass; LM then needs one or two iterations.
        False: LM from the closed form (slower, same optimum).
    state_covariances : also return each frame's state marginal (slow for
        long sequences; NaN otherwise).
    range_offset_prior_m : ``(mean, sigma)`` in metres: estimate a range
        offset ``d`` common to every node, the reflection depth of an
        extended target (each radar's centroid sits ``d`` nearer to it than
        the body's centre: range ``|p - p_i| - d``), with this Gaussian
        prior; its uncertainty enters the pose covariances
        (docs/CALIBRATION.md, "Extended targets"). None (default): no offset.
    range_offset_rms_m : when the range offset is not estimated
        (``range_offset_prior_m`` None), the root mean square (m) of the
        reflection depth it leaves in the data: the poses are not moved, but
        their long-run covariance (``covariance="long_run"``) adds ``J s^2
        J^T``, ``J`` the poses' response to every range lengthened alike (a *considered* parameter: where the
        geometry cannot tell the depth from the poses it shows in their
        covariance instead of hiding as a bias; docs/CALIBRATION.md). None
        (default): not considered (a point target); ``PEOPLE_JOINT_OPTIONS``
        (``mmsnap calibrate``, ``mmsnap batch``) uses
        :data:`REFLECTION_DEPTH_RMS_M`.
    covariance : ``"long_run"`` (default): the pose covariance widened to
        the long-run (Newey-West) covariance of the frames' influences where
        that exceeds the model's beyond its sampling noise (errors correlated
        in time, model error: :mod:`.covariance`); ``"model"``: the
        marginals of the graph alone. The long-run covariance needs
        ``frame_period_s`` (else the model's is kept).
    covariance_bandwidth_s : the Bartlett bandwidth (s) of ``"long_run"``.

    A bad value raises :class:`~mmsnap_graph.errors.ValidationError` naming
    the field.
    """

    robust: Literal["huber", "cauchy"] | None = "cauchy"
    robust_k: float | None = None
    motion: bool = False
    sigma_a_mps2: float = 1.0
    max_motion_gap_frames: int = 3
    motion_robust: Literal["huber", "cauchy"] | None = None
    motion_robust_k: float = DEFAULT_MOTION_ROBUST_K
    time_offsets: bool = False
    recentre_lags: bool = True
    state_prior_sigmas: tuple[float, float, float, float] = (1e3, 1e3, 3.5, 3.5)
    gate_probability: float = 0.999
    min_common_frames: int = DEFAULT_MIN_COMMON_FRAMES
    min_spread_m: float = DEFAULT_MIN_SPREAD_M
    max_pose_variance: float = 1.0
    max_pose_condition: float = 1e4
    max_iterations: int = 50
    presolve: bool = True
    state_covariances: bool = False
    range_offset_prior_m: tuple[float, float] | None = None
    range_offset_rms_m: float | None = None
    covariance: Literal["long_run", "model"] = "long_run"
    covariance_bandwidth_s: float = DEFAULT_BANDWIDTH_S

    def __post_init__(self) -> None:
        for name in ("robust", "motion_robust"):
            if getattr(self, name) not in _KERNELS:
                raise ValidationError(f"{name}={getattr(self, name)!r} must be None, 'huber' "
                                      f"or 'cauchy'")
        if self.robust_k is not None:
            object.__setattr__(self, "robust_k", float(check_positive(self.robust_k, "robust_k")))
        for name in ("sigma_a_mps2", "motion_robust_k", "max_pose_variance",
                     "max_pose_condition"):
            object.__setattr__(self, name, float(check_positive(getattr(self, name), name)))
        if self.min_spread_m is None or not float(self.min_spread_m) >= 0:
            raise ValidationError(f"min_spread_m must be >= 0, got {self.min_spread_m!r}")
        object.__setattr__(self, "min_spread_m", float(self.min_spread_m))
        for name in ("max_motion_gap_frames", "min_common_frames", "max_iterations"):
            object.__setattr__(self, name, check_count(getattr(self, name), name))
        for name in ("motion", "time_offsets", "recentre_lags", "presolve", "state_covariances"):
            object.__setattr__(self, name, _flag(getattr(self, name), name))
        prior = check_positive(frozen_vector(self.state_prior_sigmas, "state_prior_sigmas", 4),
                               "state_prior_sigmas")
        object.__setattr__(self, "state_prior_sigmas", tuple(float(v) for v in prior))
        object.__setattr__(self, "gate_probability",
                           check_probability(self.gate_probability, "gate_probability"))
        if self.range_offset_prior_m is not None:
            mean, sigma = frozen_vector(self.range_offset_prior_m, "range_offset_prior_m", 2)
            if not (np.isfinite(mean) and abs(mean) <= 1.0):
                raise ValidationError(f"range_offset_prior_m mean must be finite metres within "
                                      f"+-1 m, got {mean!r}")
            check_positive(sigma, "range_offset_prior_m sigma")
            object.__setattr__(self, "range_offset_prior_m", (float(mean), float(sigma)))
        if self.range_offset_rms_m is not None:
            rms = float(check_positive(self.range_offset_rms_m, "range_offset_rms_m"))
            if rms > 1.0:
                raise ValidationError(f"range_offset_rms_m must be metres up to 1 m (a body's "
                                      f"reflection depth), got {rms!r}; centimetres?")
            object.__setattr__(self, "range_offset_rms_m", rms)
        if self.covariance not in ("long_run", "model"):
            raise ValidationError(f"covariance={self.covariance!r} must be 'long_run' or "
                                  f"'model'")
        object.__setattr__(self, "covariance_bandwidth_s",
                           float(check_positive(self.covariance_bandwidth_s,
                                                "covariance_bandwidth_s")))

    @property
    def kernel_k(self) -> float | None:
        """The width of the robust kernel in use (None without one)."""
        if self.robust is None:
            return None
        return self.robust_k if self.robust_k is not None else DEFAULT_ROBUST_K[self.robust]
