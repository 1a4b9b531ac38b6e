"""Which whole-frame lags the calibrated model cannot reject, from the
centroids it was fitted on.

The track matching marks a lag ambiguous when other lags fit the tracks
about as well with other poses (a walk along a circle: a time shift is a
turn about its centre). Its fits at those lags may sit on other track pairs
(two people matched to each other) and its tracks are smoothed, so the
spread of their poses can be far wider than what the centroids allow
(docs/validation/calibration.md, "Figures behind the estimators' rules"). Here each lag is tested on the centroids that the joint graph used
(one per node and frame, or the ones it associated across nodes, the same
person paired with itself): node b's centroid of frame ``k + L`` paired with
node a's of frame ``k`` against node b's of frame ``k``, both lags' closed
forms on the same rows (:func:`~mmsnap_graph.calibration.pairwise.matching.paired_lag_evidence`).
A lag that loses to the calibrated one by ``z >= LAG_EVIDENCE_Z`` is
rejected; the others' poses widen the covariance.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from factors.models import detection_to_local

from ..data.recording import Detections
from .pairwise.matching import LAG_EVIDENCE_Z, paired_lag_evidence
from .poses import pose_tangent_error

__all__ = ["LagTest", "lags_not_rejected", "unrejected_lag_spread"]


def _keyed(det: Detections) -> dict[tuple[int, int], int]:
    """(target, frame) -> row, for the rows whose key is unique."""
    tid = np.zeros(len(det.frame), dtype=np.int64) if det.target_id is None else det.target_id
    keys, counts = {}, {}
    for row, key in enumerate(zip(tid.tolist(), np.asarray(det.frame).tolist())):
        keys[key] = row
        counts[key] = counts.get(key, 0) + 1
    return {k: r for k, r in keys.items() if counts[k] == 1}


@dataclass(frozen=True, slots=True)
class LagTest:
    """A shift's ``z`` against the calibrated pairing (positive: the shift
    fits worse; NaN: too few rows) and its closed-form pose of b in a's
    frame (None with too few rows)."""

    lag: int
    z: float
    pose: NDArray | None


def lags_not_rejected(det_a: Detections, det_b: Detections, shifts, gate_m: float
                      ) -> tuple[NDArray | None, list[LagTest]]:
    """``(lag 0's closed-form pose, tests)``: for each shift ``L`` of
    ``shifts`` (frames, nonzero) the evidence of the centroids'
    calibrated pairing (node b's frame ``k`` with a's ``k``, same target id)
    against node b's frame ``k + L`` (module doc). A test's ``z`` is NaN
    when fewer than 8 rows pair at both."""
    ka, kb = _keyed(det_a), _keyed(det_b)
    pa = detection_to_local(det_a.range_m, det_a.omega_rad)
    pb = detection_to_local(det_b.range_m, det_b.omega_rad)
    pose0, tests = None, []
    for shift in shifts:
        rows = [(ra, kb[(t, f)], kb[(t, f + shift)]) for (t, f), ra in sorted(ka.items())
                if (t, f) in kb and (t, f + shift) in kb]
        if len(rows) < 8:
            tests.append(LagTest(int(shift), float("nan"), None))
            continue
        ra, rb0, rbl = (np.array(c) for c in zip(*rows))
        z, p0, pl = paired_lag_evidence(pa[ra], pb[rb0], pb[rbl],
                                        np.asarray(det_a.frame)[ra], gate_m)
        pose0 = p0 if pose0 is None and p0 is not None else pose0
        tests.append(LagTest(int(shift), z, pl))
    return pose0, tests


def unrejected_lag_spread(det_a: Detections, det_b: Detections, shifts, gate_m: float,
                          covariance) -> tuple[NDArray, list[int], list[int]]:
    """``(extra, kept, rejected)``: the sum of ``d d^T`` (body tangent) over
    the shifts the centroids do not reject (``z < LAG_EVIDENCE_Z``, or too
    few rows to tell) whose pose lies beyond 3 sigma of ``covariance`` from
    lag 0's closed form; the shifts kept and those rejected."""
    cov = np.asarray(covariance, dtype=float)
    pose0, tests = lags_not_rejected(det_a, det_b, shifts, gate_m)
    extra, kept, rejected = np.zeros((3, 3)), [], []
    for t in tests:
        if np.isfinite(t.z) and t.z >= LAG_EVIDENCE_Z:
            rejected.append(t.lag)
            continue
        kept.append(t.lag)
        if t.pose is None or pose0 is None:
            continue
        d = pose_tangent_error(t.pose, pose0)
        if d @ np.linalg.solve(cov, d) > 9.0:
            extra += np.outer(d, d)
    return extra, kept, rejected
