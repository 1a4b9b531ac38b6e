"""Result types of the estimators and the one status enum they share.

- :class:`Status`: why a frame (of the fusion solvers, of a recording's
  ``/fused`` group, or of the radar signal chain) has no usable result, with
  the one table of its messages;
- (the one record of a one-shot solve is
  :class:`~mmsnap_graph.data.solution.FusionSolution`);
- :class:`FusedSequence`: every target of every frame of a recording
  (:func:`mmsnap_graph.fusion.recording.sequence.fuse_recording`; stored as ``/fused``
  by :mod:`mmsnap_graph.io.fused`).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ..errors import ValidationError

__all__ = ["Status", "DEGENERACY_THRESHOLD", "FusedSequence", "measurement_information"]

#: ``degeneracy`` above this flags a degenerate geometry: for two nodes, lines
#: of sight within about 11.4 degrees of parallel (the condition number of two
#: unit vectors at angle ``a`` is ``cot^2(a / 2)``), where the cross-line
#: velocity from Doppler alone is ~7x worse than along the line. Indicative
#: values at the estimate: configuration B ~1.6, A ~6, C with the target on the
#: line through the radars ~175 (median; the estimate's own cross-line error
#: makes it finite).
DEGENERACY_THRESHOLD = 100.0


class Status(enum.IntEnum):
    """Status codes of fused frames and of radar frames (one scheme).

    Codes 0-5 and 9-12 are the ``status`` dataset of a recording's ``/fused``
    group (a file contract, docs/FORMAT.md); codes 6-8 are the radar signal
    chain's (:attr:`mmsnap_graph.radar.chain.ChainResult.status`, not stored
    in files). Code 9 comes from the robust fusion (``robust="gate"``): the
    residuals fail the chi-square test and leaving out one node does not
    repair them. Code 10 comes from the motion check of a recording
    (:mod:`mmsnap_graph.fusion.recording.motion_check`): no subset of the row's
    nodes agrees with the motion of a target in the neighbouring frames. Codes
    11 and 12 come from the room-frame checks
    (:mod:`mmsnap_graph.fusion.recording.room`): a row outside the room bounds,
    a row repeating a better-supported one of its frame within a body's width.
    ``Status.OK`` is success for both.
    """

    OK = 0
    MAX_ITERATIONS = 1
    SINGULAR = 2
    NON_FINITE = 3
    NO_INFORMATION = 4
    GRID_FAILED = 5
    NON_FINITE_SAMPLES = 6
    ALL_ZERO_CUBE = 7
    SATURATED = 8
    RESIDUAL_TEST_FAILED = 9
    MOTION_INCONSISTENT = 10
    OUTSIDE_BOUNDS = 11
    DUPLICATE = 12

    @property
    def message(self) -> str:
        """A one-line description of the code."""
        return _MESSAGES[self.value]

    @classmethod
    def messages(cls) -> dict[int, str]:
        """``code -> message`` of every status (what ``/fused`` stores as JSON)."""
        return dict(_MESSAGES)


_MESSAGES = {
    0: "converged",
    1: "maximum number of iterations reached",
    2: "information matrix is not positive definite at the solution",
    3: "non-finite cost or state",
    4: "no measurement and no prior",
    5: "grid covariance failed",
    6: "non-finite samples",
    7: "all-zero cube",
    8: "saturated",
    9: "residuals fail the chi-square test and no single node's removal repairs them",
    10: "not consistent with the motion of any target in the neighbouring frames",
    11: "outside the room bounds",
    12: "within a body's width of a better-supported target of the same frame",
}


def _no_rejection(shape) -> NDArray:
    """An all-False read-only ``rejected`` mask."""
    out = np.zeros(shape, dtype=bool)
    out.setflags(write=False)
    return out


@dataclass(frozen=True, kw_only=True, slots=True)
class FusedSequence:
    """One-shot estimates of every target in every frame of a recording.

    K rows, one per fused target per frame, sorted by frame then target.

    node_names : (N,) names, in the recording's order; node_poses : (N, 3).
    mode : ``"map"`` or ``"ml"``; covariance_method : ``"laplace"`` or ``"grid"``;
    solver : ``"gtsam"``, ``"vectorized"`` or ``"scalar"`` (:data:`~mmsnap_graph.fusion.solvers.settings.SOLVERS`).
    frame, target, label : (K,) int (see :data:`mmsnap_graph.io.fused.FUSED_LAYOUT`).
    detection_index : (K, N) int; observed : (K, N) bool.
    state : (K, 4) ``(x_m, y_m, vx_mps, vy_mps)``; covariance : (K, 4, 4) the
    chosen covariance; laplace_covariance : (K, 4, 4).
    success : (K,) bool; status : (K,) int, :class:`Status` codes (0 to 5, 9 to 12);
    message : (K,) str (object array).
    iterations : (K,) int; final_cost, degeneracy : (K,) float.
    noise_sigmas : (3,); prior_mean, prior_sigmas : (4,) or None (ML);
    gate_probability : float.
    rejected : (K, N) bool, the nodes the robust fusion left out or
    down-weighted (``FusionSolution.rejected``); all False without ``robust``.
    robust : the robust option used (None, ``"gate"``, ``"huber"``, ``"cauchy"``).
    time_s : (K,) float or None, seconds since the recording's start
    (``frame * frame_period_s``); filled from ``frame_period_s`` when that is
    given, else None (:func:`mmsnap_graph.io.fused.write_fused` fills it
    from the recording file).
    frame_period_s : float or None, the recording's frame period.
    time_origin_s : float or None, the wall-clock time (Unix seconds) of
    ``time_s = 0`` when the recording holds one (its ``time_origin_s``
    metadata, from time-stamped imports).
    information, information_vector : (K, 4, 4), (K, 4): the prior-free
    information form of each row (:func:`measurement_information`): what the
    measurements alone say about the state, for a tracker that brings its own
    prior. Computed from ``laplace_covariance`` when not given.
    track_id : (K,) int64 or None, the person id of each row: the central
    tracker's track that the row updated or started
    (:class:`mmsnap_graph.tracking.person_ids.PersonIds`); -1 for a row that
    was not fused successfully. None: not tracked (files of format 1.1 and
    older).
    """

    node_names: tuple
    node_poses: NDArray
    mode: str
    covariance_method: str
    solver: str
    frame: NDArray
    target: NDArray
    label: NDArray
    detection_index: NDArray
    observed: NDArray
    state: NDArray
    covariance: NDArray
    laplace_covariance: NDArray
    success: NDArray
    status: NDArray
    message: NDArray
    iterations: NDArray
    final_cost: NDArray
    degeneracy: NDArray
    noise_sigmas: NDArray
    prior_mean: NDArray | None
    prior_sigmas: NDArray | None
    gate_probability: float
    rejected: NDArray | None = None
    robust: str | None = None
    time_s: NDArray | None = None
    frame_period_s: float | None = None
    time_origin_s: float | None = None
    information: NDArray | None = None
    information_vector: NDArray | None = None
    track_id: NDArray | None = None

    def __post_init__(self) -> None:
        if self.track_id is not None:
            tid = np.asarray(self.track_id)
            if tid.shape != np.shape(self.frame) or not np.issubdtype(tid.dtype, np.integer):
                raise ValidationError(f"track_id must be an integer array of shape "
                                      f"{np.shape(self.frame)} like frame, got {tid.dtype} "
                                      f"{tid.shape}")
            object.__setattr__(self, "track_id", tid.astype(np.int64, copy=False))
        if self.rejected is None:
            object.__setattr__(self, "rejected", _no_rejection(np.shape(self.observed)))
        if self.frame_period_s is not None:
            object.__setattr__(self, "frame_period_s", float(self.frame_period_s))
        if self.time_s is None and self.frame_period_s is not None:
            object.__setattr__(self, "time_s",
                               np.asarray(self.frame, dtype=float) * self.frame_period_s)
        if self.information is None or self.information_vector is None:
            info, vec = measurement_information(self.state, self.laplace_covariance,
                                                self.prior_mean, self.prior_sigmas)
            object.__setattr__(self, "information", info)
            object.__setattr__(self, "information_vector", vec)

    def __len__(self) -> int:
        return int(self.frame.shape[0])

    def rows_of_label(self, label: int) -> NDArray:
        """Row indices of one labelled target, in frame order."""
        rows = np.flatnonzero(self.label == label)
        return rows[np.argsort(self.frame[rows], kind="stable")]


def _spd_inverse(cov: NDArray) -> NDArray:
    """Inverses of symmetric matrices ``(K, D, D)``; NaN for a matrix that is
    not positive definite (or too ill-conditioned to invert)."""
    try:
        # The common case, every matrix positive definite: one batched
        # Cholesky checks it (a failure anywhere fails the whole stack).
        np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        # Eigendecomposition: a row that is not positive definite becomes NaN.
        w, v = np.linalg.eigh(cov)
        pd = np.all(w > 0.0, axis=1) & (w[:, 0] > 1e-14 * np.abs(w[:, -1]))
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = np.einsum("kij,kj,klj->kil", v, 1.0 / w, v)
        inv[~pd] = np.nan
        return inv
    return np.linalg.inv(cov)


def measurement_information(state, covariance, prior_mean=None, prior_sigmas=None
                            ) -> tuple[NDArray, NDArray]:
    """The prior-free information form of fused estimates.

    state : (K, 4) MAP (or ML) ``(x_m, y_m, vx_mps, vy_mps)``; covariance :
    (K, 4, 4) their Laplace covariances (the inverse Gauss-Newton information
    at ``state``, prior included for MAP); prior_mean, prior_sigmas : (4,)
    the Gaussian prior used, None for ML.

    Returns ``information (K, 4, 4)``, the measurements' information at the
    estimate, and ``information_vector (K, 4)``:

    .. math::

        Y = P^{-1} - P_0^{-1}, \\qquad y = P^{-1} \\hat x - P_0^{-1} m_0

    (``P0 = diag(prior_sigmas^2)``, ``m0 = prior_mean``; for ML ``Y = P^-1``,
    ``y = Y x``). ``Y`` is ``J^T W J`` summed over the nodes kept (J the
    measurement Jacobian at the estimate, W the inverse measurement
    variances, robust weights included) and ``(Y, y)`` is the linearised
    measurement evidence with the prior taken out: an information filter
    adds them to its own prediction, and where ``Y`` is invertible
    ``Y^-1 y`` is the prior-free state (to first order, the ML estimate) with
    covariance ``Y^-1``. A MAP covariance includes the prior; a tracker that
    brings its own prior must use this form, or it counts the prior again at
    every frame. ``Y`` may be singular (one node: no cross-line velocity).
    Rows whose covariance is not finite or not positive definite are NaN.
    """
    x = np.asarray(state, dtype=float)
    cov = np.asarray(covariance, dtype=float)
    k = x.shape[0]
    info = np.full((k, 4, 4), np.nan)
    vec = np.full((k, 4), np.nan)
    ok = np.all(np.isfinite(cov), axis=(1, 2)) & np.all(np.isfinite(x), axis=1)
    if np.any(ok):
        rows = np.flatnonzero(ok)
        inv = _spd_inverse(0.5 * (cov[rows] + np.swapaxes(cov[rows], -1, -2)))
        info[rows] = inv
        vec[rows] = np.einsum("kij,kj->ki", inv, x[rows])
    if prior_sigmas is not None:
        p0 = 1.0 / np.asarray(prior_sigmas, dtype=float) ** 2
        m0 = np.zeros(4) if prior_mean is None else np.asarray(prior_mean, dtype=float)
        info = info - np.diag(p0)
        vec = vec - p0 * m0
    info = 0.5 * (info + np.swapaxes(info, -1, -2))
    info.setflags(write=False)
    vec.setflags(write=False)
    return info, vec
