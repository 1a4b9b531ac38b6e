"""The range offset (a body's reflection depth) at known node poses.

A radar sees the near side of a body: its centroid sits about ``d`` metres
closer than the body's centre (docs/CALIBRATION.md, "Extended targets").
Where the node poses are free (the calibration), ``d`` trades against them
(a shorter baseline and a deeper body look alike) and the joint graph needs
a prior for it. At poses fixed from outside the data (surveyed, or the
truth of a simulation, passed to ``mmsnap fuse --calibration``), the
cross-node residuals identify one common ``d`` well (at the calibrated
poses it is about zero: the poses took it in; docs/CALIBRATION.md,
"Extended targets: a range offset").

:func:`range_offset_at_poses` is the generalised least-squares estimate of
``d`` with every frame's state a free nuisance: the score and information of
``d`` from the frames' residual projections (``R = W - W J C J^T W``, as the
network noise estimator), a few Gauss-Newton rounds, frames with a residual
beyond :data:`GATE_K` standard deviations left out (ghosts).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np
from numpy.typing import NDArray

from ...data.noise import MeasurementNoise
from ...data.recording import Detections, Recording
from ...errors import ValidationError
from .frame_states import frame_table, solve_frame_states, without_unsolved
from .sequences import ghost_rows

__all__ = ["RangeOffsetEstimate", "range_offset_at_poses", "GATE_K", "MAX_SIGMA_M", "MIN_FRAMES"]

#: Frames with a standardised residual beyond this are left out (ghosts).
GATE_K = 4.0
#: The offset counts as identified when its standard error is at most this
#: (metres; a third of the issue's physical prior sigma of 0.05 m) ...
MAX_SIGMA_M = 0.015
#: ... from at least this many frames seen by two nodes or more.
MIN_FRAMES = 30
_ROUNDS = 3


@dataclass(frozen=True, kw_only=True, slots=True)
class RangeOffsetEstimate:
    """offset_m : the range to add to every centroid (NaN when none could
    be computed); variance_m2 : its variance; n_frames : frames used;
    identified : standard error <= :data:`MAX_SIGMA_M` on at least
    :data:`MIN_FRAMES` frames; message : what it is, in words."""

    offset_m: float
    variance_m2: float
    n_frames: int
    identified: bool
    message: str


def _aligned(recording: Recording, lag_frames) -> dict[str, Detections]:
    out = {}
    for n in recording.node_names:
        det = recording.nodes[n].centroids
        if det is None or len(det) == 0:
            continue
        lag = int((lag_frames or {}).get(n, 0))
        det = Detections(frame=det.frame - lag, range_m=det.range_m, omega_rad=det.omega_rad,
                         doppler_mps=det.doppler_mps, target_id=det.target_id)
        out[n] = det.select(~ghost_rows(det))
    return out


def _round(z, p, w, d):
    """Score and information of the offset ``d`` (and the frames kept)."""
    zz = z.copy()
    zz[..., 0] += d
    _, e, jac, cov = solve_frame_states(zz, p, w, np.full(4, 1e-6))
    w, jac, cov = without_unsolved(w, jac, cov)
    f, n = z.shape[:2]
    wf = w.reshape(f, 3 * n)
    wj = wf[..., None] * jac.reshape(f, 3 * n, 4)
    r = -np.einsum("fia,fab,fjb->fij", wj, cov, wj)
    r[:, np.arange(3 * n), np.arange(3 * n)] += wf
    ef = np.nan_to_num(e.reshape(f, 3 * n)) * (wf > 0)
    keep = np.all(np.abs(ef) * np.sqrt(wf) <= GATE_K, axis=1)
    rng = np.arange(0, 3 * n, 3)
    score = float(np.sum((wf * ef)[keep][:, rng]))
    info = float(np.sum(r[keep][:, rng][:, :, rng]))
    return score, info, int(np.count_nonzero(keep))


def range_offset_at_poses(recording: Recording, poses: Mapping[str, NDArray], *,
                          noise: MeasurementNoise | Mapping[str, MeasurementNoise],
                          lag_frames: Mapping[str, int] | None = None) -> RangeOffsetEstimate:
    """One range offset common to every node of ``recording`` at the fixed
    ``poses`` (module doc), from the frames that two nodes or more see with
    one centroid each.

    poses : name -> (3,) pose; noise : one :class:`MeasurementNoise` or one
        per node (the weights); lag_frames : name -> whole-frame lag (node
        frame k + lag = reference frame k), default 0.
    Never raises on data that say nothing: ``identified`` False and why.
    """
    if not isinstance(recording, Recording):
        raise ValidationError(f"recording must be a Recording, got {type(recording).__name__}")
    dets = _aligned(recording, lag_frames)
    names = [n for n in dets if n in poses and poses[n] is not None]
    none = RangeOffsetEstimate(offset_m=float("nan"), variance_m2=float("nan"), n_frames=0,
                               identified=False, message="")
    if len(names) < 2:
        return _replace_msg(none, "fewer than two nodes with a pose and centroids")
    frames, z = frame_table({n: dets[n] for n in names}, names)
    if frames.size < MIN_FRAMES:
        return _replace_msg(none, f"{frames.size} frames seen by two nodes or more "
                                  f"({MIN_FRAMES} needed)")
    sig = np.array([(noise[n] if isinstance(noise, Mapping) else noise).sigmas for n in names])
    p = np.array([np.asarray(poses[n], dtype=float) for n in names])
    w = np.where(np.isfinite(z[..., :1]), 1.0 / sig[None] ** 2, 0.0)
    d, info, kept = 0.0, 0.0, 0
    for _ in range(_ROUNDS):
        score, info, kept = _round(z, p, w, d)
        if not info > 0:
            return _replace_msg(none, "the cross-node residuals do not see a range offset")
        d = float(np.clip(d + score / info, -1.0, 1.0))
    var = 1.0 / info
    ok = bool(kept >= MIN_FRAMES and np.sqrt(var) <= MAX_SIGMA_M)
    msg = (f"range offset at these poses {d:+.3f} +- {np.sqrt(var):.3f} m from {kept} frames"
           + ("" if ok else f" (not identified: {MAX_SIGMA_M} m standard error and "
                            f"{MIN_FRAMES} frames needed)"))
    return RangeOffsetEstimate(offset_m=d, variance_m2=var, n_frames=kept, identified=ok,
                               message=msg)


def _replace_msg(est: RangeOffsetEstimate, why: str) -> RangeOffsetEstimate:
    return RangeOffsetEstimate(offset_m=est.offset_m, variance_m2=est.variance_m2,
                               n_frames=est.n_frames, identified=False,
                               message=f"range offset at these poses not identified: {why}")
