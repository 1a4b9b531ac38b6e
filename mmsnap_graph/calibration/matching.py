"""Track matching between two nodes: which tracks are one target, and the
frame lag between the nodes (paper Sec. II: "the nodes are coarsely
time-synchronized at the level of a radar frame").

For every pair of tracks ``(a, b)`` and every lag ``L`` in
``[-max_lag_frames, max_lag_frames]``, node b's frame ``k + L`` is paired
with node a's frame ``k`` and the closed form (paper eq. 12) is fitted on the
common frames; the track RMSE (eq. 14) scores the candidate. The node pair's
lag is the lag of the lowest-RMSE candidate (a clock offset belongs to the
node pair, and the best-matching target shows it most clearly), provided it
lowers the RMSE by ``lag_min_improvement`` over lag 0. At that lag,
candidates are accepted greedily by increasing RMSE, one-to-one, when their
RMSE is below ``max_rmse_m`` and their pose agrees with the best candidate's
(several targets seen by both nodes must give the same pose). The final
estimate is the closed form on all accepted pairs' frames stacked.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from factors.models import detection_to_local, wrap_angle

from ..errors import CalibrationError, ValidationError
from ..recording import NodeData
from ..validation import as_float_array, check_finite, check_shape
from .closed_form import (
    DEFAULT_MIN_COMMON_FRAMES,
    DEFAULT_MIN_SPREAD_M,
    PairwiseCalibration,
    closed_form_calibration,
    closed_form_pose,
)

__all__ = ["LocalTracks", "TrackCandidate", "TrackMatching", "match_tracks", "local_tracks"]


@dataclass(frozen=True, kw_only=True, slots=True)
class LocalTracks:
    """A node's target positions in its local frame, one row per track per frame.

    frame : (K,) int; points_m : (K, 2) float; track_id : (K,) int;
    source : where they came from (``"tracks"`` or ``"centroids"``).
    """

    frame: NDArray
    points_m: NDArray
    track_id: NDArray
    source: str = "tracks"

    def __post_init__(self) -> None:
        frame = np.asarray(self.frame)
        if frame.ndim != 1:
            raise ValidationError(f"frame must be 1-D, got shape {frame.shape}")
        k = frame.shape[0]
        pts = check_finite(check_shape(as_float_array(self.points_m, "points_m"), (k, 2),
                                       "points_m"), "points_m")
        tid = np.asarray(self.track_id)
        if tid.shape != (k,):
            raise ValidationError(f"track_id must have shape ({k},) like frame, got {tid.shape}")
        object.__setattr__(self, "frame", frame.astype(np.int64))
        object.__setattr__(self, "points_m", pts)
        object.__setattr__(self, "track_id", tid.astype(np.int64))

    def split(self) -> dict[int, tuple[NDArray, NDArray]]:
        """track id -> (frames (n,), points (n, 2)), frame-sorted, one row per
        frame (a repeated frame keeps its first row)."""
        out = {}
        for tid in np.unique(self.track_id):
            rows = np.flatnonzero(self.track_id == tid)
            rows = rows[np.argsort(self.frame[rows], kind="stable")]
            fr, first = np.unique(self.frame[rows], return_index=True)
            out[int(tid)] = (fr, self.points_m[rows[first]])
        return out


def local_tracks(node: NodeData, source: str = "auto") -> LocalTracks:
    """A node's local target positions: its EKF tracks when it has them
    (``source="auto"`` or ``"tracks"``), else its centroids mapped with
    ``factors.detection_to_local`` (track id = ``target_id``, ``-1`` when
    unlabelled). Raises :class:`CalibrationError` when neither exists or when
    unlabelled centroids hold several detections in one frame."""
    if source not in ("auto", "tracks", "centroids"):
        raise ValidationError(f"source={source!r} must be 'auto', 'tracks' or 'centroids'")
    if source in ("auto", "tracks") and node.tracks is not None and len(node.tracks):
        tr = node.tracks
        return LocalTracks(frame=tr.frame, points_m=tr.state[:, :2], track_id=tr.track_id,
                           source="tracks")
    if source == "tracks":
        raise CalibrationError(f"node {node.name} has no tracks")
    det = node.centroids
    if det is None or len(det) == 0:
        raise CalibrationError(f"node {node.name} has neither tracks nor centroids to calibrate from")
    tid = (np.full(len(det), -1, np.int64) if det.target_id is None else det.target_id)
    for t in np.unique(tid):
        fr = det.frame[tid == t]
        if np.unique(fr).size != fr.size:
            raise CalibrationError(
                f"node {node.name}: centroids with target_id {int(t)} hold several detections "
                f"in one frame; label them (target_id) or track them first")
    return LocalTracks(frame=det.frame, points_m=detection_to_local(det.range_m, det.omega_rad),
                       track_id=tid, source="centroids")


@dataclass(frozen=True, kw_only=True, slots=True)
class TrackCandidate:
    """One (track a, track b, lag) hypothesis scored by the closed form."""

    track_a: int
    track_b: int
    lag_frames: int
    n_frames: int
    rmse_m: float
    pose: NDArray
    accepted: bool = False


@dataclass(frozen=True, kw_only=True, slots=True)
class TrackMatching:
    """Result of :func:`match_tracks`.

    calibration : the closed form on all accepted pairs (None on failure).
    pairs : accepted ``(track_a, track_b)`` pairs.
    lag_frames : node b's frame ``k + lag`` matches node a's frame ``k``.
    candidates : every scored hypothesis.
    """

    calibration: PairwiseCalibration | None
    pairs: tuple[tuple[int, int], ...]
    lag_frames: int
    candidates: tuple[TrackCandidate, ...]
    success: bool
    message: str


def _common(fa: NDArray, fb: NDArray, lag: int) -> tuple[NDArray, NDArray]:
    _, ia, ib = np.intersect1d(fa, fb - lag, assume_unique=True, return_indices=True)
    return ia, ib


def match_tracks(
    tracks_a: LocalTracks,
    tracks_b: LocalTracks,
    *,
    max_lag_frames: int = 2,
    min_common_frames: int = DEFAULT_MIN_COMMON_FRAMES,
    min_spread_m: float = DEFAULT_MIN_SPREAD_M,
    max_rmse_m: float = 1.0,
    max_pose_disagreement: tuple[float, float] = (0.5, np.radians(10.0)),
    covariance: str = "residual",
    lag_min_improvement: float = 0.05,
) -> TrackMatching:
    """Match two nodes' local tracks and calibrate b in a's frame (module doc).

    Parameters
    ----------
    tracks_a, tracks_b : LocalTracks
    max_lag_frames : int
        Lags ``-max_lag_frames..max_lag_frames`` are searched.
    min_common_frames, min_spread_m : as :func:`closed_form_calibration`;
        candidates that fail them are skipped.
    max_rmse_m : float
        Candidates with a larger track RMSE are not one target.
    max_pose_disagreement : (m, rad)
        How far an accepted pair's pose may be from the best pair's.
    covariance : passed to :func:`closed_form_calibration`.
    lag_min_improvement : float
        A nonzero lag is reported only if its best track RMSE is at least this
        fraction below the best at lag 0; a slow target in noisy tracks shows
        no lag, and the RMSE differences between lags are then noise.

    Returns a :class:`TrackMatching`; ``success=False`` (no calibration) when
    no candidate has enough common frames, a moving target and a small RMSE.
    """
    if int(max_lag_frames) < 0:
        raise ValidationError(f"max_lag_frames must be >= 0, got {max_lag_frames!r}")
    if not max_rmse_m > 0:
        raise ValidationError(f"max_rmse_m must be > 0, got {max_rmse_m!r}")
    ta, tb = tracks_a.split(), tracks_b.split()
    cands: list[TrackCandidate] = []
    for ida, (fa, pa) in ta.items():
        for idb, (fb, pb) in tb.items():
            for lag in range(-int(max_lag_frames), int(max_lag_frames) + 1):
                ia, ib = _common(fa, fb, lag)
                if ia.size < max(min_common_frames, 3):
                    continue
                za, zb = pa[ia], pb[ib]
                spread = min(np.sqrt(np.mean(np.sum((za - za.mean(0)) ** 2, 1))),
                             np.sqrt(np.mean(np.sum((zb - zb.mean(0)) ** 2, 1))))
                if spread < min_spread_m:
                    continue
                pose, j = closed_form_pose(za, zb)
                cands.append(TrackCandidate(track_a=ida, track_b=idb, lag_frames=lag,
                                            n_frames=int(ia.size),
                                            rmse_m=float(np.sqrt(j / ia.size)), pose=pose))
    if not cands:
        return TrackMatching(
            calibration=None, pairs=(), lag_frames=0, candidates=(), success=False,
            message=(f"no pair of tracks shares >= {max(min_common_frames, 3)} frames of a "
                     f"moving target (spread >= {min_spread_m} m) within +-{max_lag_frames} "
                     f"frames of lag"))
    order = sorted(range(len(cands)), key=lambda i: cands[i].rmse_m)
    best = cands[order[0]]
    if best.rmse_m > max_rmse_m:
        return TrackMatching(
            calibration=None, pairs=(), lag_frames=0, candidates=tuple(cands), success=False,
            message=(f"no pair of tracks matches: the best track RMSE {best.rmse_m:.3g} m "
                     f"(tracks {best.track_a}/{best.track_b}, lag {best.lag_frames}) exceeds "
                     f"max_rmse_m={max_rmse_m}"))
    zero = [i for i in order if cands[i].lag_frames == 0]
    if best.lag_frames != 0 and zero and best.rmse_m > (1.0 - lag_min_improvement) * cands[zero[0]].rmse_m:
        best = cands[zero[0]]  # the data do not show a lag: keep the nodes' own sync
    lag = best.lag_frames
    used_a, used_b, accepted = set(), set(), []
    for i in order:
        c = cands[i]
        if c.lag_frames != lag or c.rmse_m > max_rmse_m:
            continue
        if c.track_a in used_a or c.track_b in used_b:
            continue
        dpos = np.hypot(*(c.pose[:2] - best.pose[:2]))
        dphi = abs(wrap_angle(c.pose[2] - best.pose[2]))
        if dpos > max_pose_disagreement[0] or dphi > max_pose_disagreement[1]:
            continue
        used_a.add(c.track_a)
        used_b.add(c.track_b)
        accepted.append(i)
    za_all, zb_all, fr_all = [], [], []
    for i in accepted:
        c = cands[i]
        fa, pa = ta[c.track_a]
        fb, pb = tb[c.track_b]
        ia, ib = _common(fa, fb, lag)
        za_all.append(pa[ia])
        zb_all.append(pb[ib])
        fr_all.append(fa[ia])
        cands[i] = replace(c, accepted=True)
    cal = closed_form_calibration(np.concatenate(za_all), np.concatenate(zb_all),
                                  covariance=covariance, min_common_frames=min_common_frames,
                                  min_spread_m=min_spread_m, frames=np.concatenate(fr_all))
    pairs = tuple((cands[i].track_a, cands[i].track_b) for i in accepted)
    single = len(pairs) == 1
    cal = replace(
        cal, lag_frames=lag, track_a=pairs[0][0] if single else -1,
        track_b=pairs[0][1] if single else -1,
        message=f"{len(pairs)} matched track pair(s) at lag {lag} frames; {cal.message}")
    return TrackMatching(calibration=cal, pairs=pairs, lag_frames=lag, candidates=tuple(cands),
                         success=True, message=cal.message)
