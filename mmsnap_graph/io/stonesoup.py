"""Hand the one-shot estimates of ``/fused`` to a Stone Soup tracker.

Stone Soup (dstl/Stone-Soup) is optional: ``pip install ".[stonesoup]"``.
It is imported when a function here is called, so this module imports
without it.

:func:`fused_detections` turns a :class:`~mmsnap_graph.data.results.FusedSequence`
(:func:`mmsnap_graph.io.fused.read_fused`) into Stone Soup scans: one
``(datetime, {Detection, ...})`` per fused frame, in time order, each
:class:`~stonesoup.types.detection.Detection` with its own
:class:`~stonesoup.models.measurement.linear.LinearGaussian` measurement model
that carries the fused covariance. Stone Soup's state order is
``(x, vx, y, vy)`` (:data:`STONESOUP_ORDER`); this library's is
``(x, y, vx, vy)``: states and covariances are reindexed here.

By default the detections are **prior-free**: a MAP covariance includes the
prior, and a tracker that updates with it frame after frame counts the prior
again at every frame. Each detection is instead the information form's
pseudo-measurement ``Y^-1 y`` with covariance ``Y^-1``
(:func:`mmsnap_graph.data.results.measurement_information`; docs/FORMAT.md):
the measurements' evidence alone, to first order the ML estimate. Rows whose
``Y`` is not invertible (a target seen by one node: no cross-line velocity)
or whose fusion failed are left out.

Example::

    scans = fused_detections(read_fused("rec.h5"))
    for time, detections in scans:
        ...  # predictor.predict(track, timestamp=time), updater.update(hypothesis)
"""

from __future__ import annotations

import datetime as dt
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from ..data.results import FusedSequence
from ..errors import MmsnapError, ValidationError

__all__ = ["STONESOUP_ORDER", "EPOCH", "to_stonesoup_order", "fused_detections"]

#: Our state index of each of Stone Soup's components ``(x, vx, y, vy)``.
STONESOUP_ORDER = (0, 2, 1, 3)

#: Time 0 of the detections when the recording holds no wall-clock time
#: origin and no ``start_time`` is given (naive UTC, like Stone Soup's).
EPOCH = dt.datetime(1970, 1, 1)


def _stonesoup():
    """The Stone Soup classes used here (imported on first use: optional extra)."""
    try:
        from stonesoup.models.measurement.linear import LinearGaussian
        from stonesoup.types.array import CovarianceMatrix, StateVector
        from stonesoup.types.detection import Detection
    except ImportError as exc:
        raise MmsnapError(
            'Stone Soup is not installed; install the optional extra: '
            'pip install "mmsnap_graph[stonesoup]" (or pip install ".[stonesoup]" from the '
            f'repository) ({exc})') from None
    return LinearGaussian, CovarianceMatrix, StateVector, Detection


def to_stonesoup_order(state: NDArray, covariance: NDArray) -> tuple[NDArray, NDArray]:
    """``(x, y, vx, vy)`` states ``(..., 4)`` and covariances ``(..., 4, 4)``
    reindexed to Stone Soup's ``(x, vx, y, vy)``."""
    idx = np.asarray(STONESOUP_ORDER)
    s = np.asarray(state, dtype=float)
    c = np.asarray(covariance, dtype=float)
    return s[..., idx], c[..., idx[:, None], idx[None, :]]


def _prior_free_rows(fused: FusedSequence) -> tuple[NDArray, NDArray, NDArray]:
    """``(rows, state, covariance)`` of the information form's
    pseudo-measurements ``Y^-1 y``, ``Y^-1`` where ``Y`` is positive definite."""
    info = np.asarray(fused.information, dtype=float)
    vec = np.asarray(fused.information_vector, dtype=float)
    ok = np.asarray(fused.success, dtype=bool) & np.all(np.isfinite(info), axis=(1, 2)) \
        & np.all(np.isfinite(vec), axis=1)
    rows = np.flatnonzero(ok)
    if rows.size == 0:
        return rows, np.zeros((0, 4)), np.zeros((0, 4, 4))
    w, v = np.linalg.eigh(info[rows])
    # Invertible: every eigenvalue positive and the condition number finite
    # in double precision (one node leaves the cross-line velocity at ~0).
    pd = np.all(w > 0.0, axis=1) & (w[:, 0] > 1e-10 * w[:, -1])
    rows, w, v = rows[pd], w[pd], v[pd]
    cov = np.einsum("kij,kj,klj->kil", v, 1.0 / w, v)
    cov = 0.5 * (cov + np.swapaxes(cov, -1, -2))
    state = np.einsum("kij,kj->ki", cov, vec[rows])
    return rows, state, cov


def _start_time(fused: FusedSequence, start_time: dt.datetime | None) -> dt.datetime:
    if start_time is not None:
        if not isinstance(start_time, dt.datetime):
            raise ValidationError(f"start_time must be a datetime.datetime, got {start_time!r}")
        return start_time
    origin = 0.0 if fused.time_origin_s is None else float(fused.time_origin_s)
    return _shifted(EPOCH, origin, "time_origin_s (Unix seconds)")


def _shifted(t0: dt.datetime, seconds: float, what: str) -> dt.datetime:
    """``t0 + seconds`` as a datetime; a NaN, infinite or out-of-calendar
    value (beyond year 9999) is a ValidationError naming ``what``."""
    try:
        if not np.isfinite(seconds):
            raise OverflowError
        return t0 + dt.timedelta(seconds=float(seconds))
    except OverflowError:
        raise ValidationError(f"{what}={seconds!r} from {t0.isoformat()} is not a time a "
                              f"datetime holds (finite, years 1-9999)") from None


def fused_detections(
    fused: FusedSequence,
    *,
    form: Literal["prior_free", "fused"] = "prior_free",
    start_time: dt.datetime | None = None,
    frame_period_s: float | None = None,
) -> list[tuple[dt.datetime, set]]:
    """Stone Soup scans of a fused recording.

    fused : the ``/fused`` group (:func:`mmsnap_graph.io.fused.read_fused`).
    form : ``"prior_free"`` (default): each detection is the information
        form's pseudo-measurement (state ``Y^-1 y``, covariance ``Y^-1``; the
        prior of a MAP fusion taken out); rows whose ``Y`` is singular are
        left out. ``"fused"``: the fused state and ``covariance`` as they are
        (a MAP covariance includes the prior: a tracker with its own prior
        counts it twice).
    start_time : the time of ``time_s = 0``; default the recording's
        wall-clock origin (``fused.time_origin_s``, Unix seconds, naive UTC)
        when it has one, else :data:`EPOCH`.
    frame_period_s : the frame period, for a sequence without ``time_s``.

    Returns one ``(timestamp, detections)`` per frame with a fused row, in
    time order (a frame whose rows were all left out has an empty set, so a
    tracker still predicts through it). Each detection's ``state_vector`` is
    ``(x, vx, y, vy)``; its ``measurement_model`` is a ``LinearGaussian``
    with ``ndim_state=4``, ``mapping=(0, 1, 2, 3)`` and the row's covariance
    in that order as ``noise_covar``; ``metadata`` holds ``frame``,
    ``target``, ``label`` and ``row`` (the ``/fused`` row).
    """
    LinearGaussian, CovarianceMatrix, StateVector, Detection = _stonesoup()
    if not isinstance(fused, FusedSequence):
        raise ValidationError(f"fused must be a FusedSequence, got {type(fused).__name__}")
    if form not in ("prior_free", "fused"):
        raise ValidationError(f"form must be 'prior_free' or 'fused', got {form!r}")
    time_s = fused.time_s
    if frame_period_s is not None:
        fp = float(frame_period_s)
        if not (np.isfinite(fp) and fp > 0):
            raise ValidationError(f"frame_period_s={frame_period_s!r} must be finite and > 0")
        time_s = np.asarray(fused.frame, dtype=float) * fp
    if time_s is None:
        raise ValidationError("the fused sequence has no time_s; pass frame_period_s=")
    time_s = np.asarray(time_s, dtype=float)
    if form == "prior_free":
        rows, state, cov = _prior_free_rows(fused)
    else:
        rows = np.flatnonzero(np.asarray(fused.success, dtype=bool)
                              & np.all(np.isfinite(fused.covariance), axis=(1, 2)))
        state, cov = np.asarray(fused.state)[rows], np.asarray(fused.covariance)[rows]
    state, cov = to_stonesoup_order(state, cov)
    t0 = _start_time(fused, start_time)
    frames, first = np.unique(np.asarray(fused.frame), return_index=True)
    stamps = {i: _shifted(t0, float(time_s[i]), f"time_s[{i}]")
              for i in sorted(set(rows.tolist()) | set(first.tolist()))}
    first_row = dict(zip(frames.tolist(), first.tolist()))
    scans = {f: set() for f in frames.tolist()}
    for j, i in enumerate(rows):
        model = LinearGaussian(ndim_state=4, mapping=(0, 1, 2, 3),
                               noise_covar=CovarianceMatrix(cov[j]))
        stamp = stamps[i]
        scans[int(fused.frame[i])].add(Detection(
            StateVector(state[j]), timestamp=stamp, measurement_model=model,
            metadata={"frame": int(fused.frame[i]), "target": int(fused.target[i]),
                      "label": int(fused.label[i]), "row": int(i)}))
    out = [(stamps[first_row[f]], scans[f]) for f in scans]
    out.sort(key=lambda scan: scan[0])
    return out
