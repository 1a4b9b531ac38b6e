"""Track matching between two nodes: which tracks are one target, and the
frame lag between the nodes (paper Sec. II: "the nodes are coarsely
time-synchronized at the level of a radar frame").

For every pair of tracks ``(a, b)`` and every lag ``L`` in
``[-max_lag_frames, max_lag_frames]``, node b's frame ``k + L`` is paired
with node a's frame ``k`` and the closed form (paper eq. 12) is fitted on the
common frames: each fit is a pose hypothesis. A hypothesis is scored by its
*support*: how many frame pairs of all the two nodes' tracks (every track, at
that lag) it aligns within the inlier gate. When both nodes' tracks carry
position covariances (EKF tracks), the gate is a chi-square test on each
frame pair, ``r^T (C_a + R C_b R^T)^{-1} r < chi2_2(gate_probability)``,
``r = z_a - T(z_b)``: it widens with range and along the cross-range axis as
the tracks' own uncertainty does (a fixed gate cuts the tails of far tracks'
residuals and the covariance comes out too small at longer ranges). Without covariances the gate is ``inlier_gate_m``.

Thresholds in time: the lag window ``max_lag_s`` and the minimum overlap
``min_common_s`` of the :class:`MatchingOptions` are seconds, turned into
frames at the recording's ``frame_period_s`` (at least 5 common frames), so
that one setting works from 5 to 30 fps. Ranking by track RMSE instead
would favour short fragments, which fit anything (an EKF that loses a walker
at each turn leaves dozens of them). The best-supported hypothesis of each
lag is refitted on its inliers (twice); lag 0 is kept unless another lag
explains as many frames with an RMSE at least ``lag_min_improvement`` lower
(a slow target in noisy tracks shows no lag, and the RMSE differences between
lags are then noise). The final estimate is the closed form on the inliers;
the accepted pairs are the track pairs that contribute inliers (several
targets seen by both nodes all agree with the one pose).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from factors.models import detection_to_local

from ...errors import CalibrationError, MissingStepError, ValidationError
from ...data.calibration import PairwiseCalibration
from ...data.calibration_facts import LagEvidence
from ...data.recording import NodeData
from ..._validation import as_float_array, check_finite, check_shape, chi2_gate
from ..poses import pose_tangent_error
from .closed_form import closed_form_calibration, closed_form_pose
from .effective_samples import autocorrelation_factor
from .matching_options import MatchingOptions

__all__ = ["LocalTracks", "TrackCandidate", "TrackMatching", "match_tracks", "local_tracks"]


@dataclass(frozen=True, kw_only=True, slots=True)
class LocalTracks:
    """A node's target positions in its local frame, one row per track per frame.

    frame : (K,) int; points_m : (K, 2) float; track_id : (K,) int;
    source : where they came from (``"tracks"`` or ``"centroids"``).
    covariances : (K, 2, 2) float position covariances (an EKF's), optional:
        with them the matching gate is a chi-square test (module doc).
    """

    frame: NDArray
    points_m: NDArray
    track_id: NDArray
    source: str = "tracks"
    covariances: NDArray | None = None

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
        if self.covariances is not None:
            cov = check_finite(check_shape(as_float_array(self.covariances, "covariances"),
                                           (k, 2, 2), "covariances"), "covariances")
            object.__setattr__(self, "covariances", 0.5 * (cov + np.swapaxes(cov, -1, -2)))

    def split(self) -> dict[int, tuple[NDArray, NDArray]]:
        """track id -> (frames (n,), points (n, 2)), frame-sorted, one row per
        frame (a repeated frame keeps its first row)."""
        return {t: (f, p) for t, (f, p, _) in self.split_rows().items()}

    def split_rows(self) -> dict[int, tuple[NDArray, NDArray, NDArray]]:
        """As :meth:`split`, plus the rows' (n, 2, 2) covariances (NaN when
        the tracks carry none)."""
        out = {}
        for tid in np.unique(self.track_id):
            rows = np.flatnonzero(self.track_id == tid)
            rows = rows[np.argsort(self.frame[rows], kind="stable")]
            fr, first = np.unique(self.frame[rows], return_index=True)
            cov = (np.full((fr.size, 2, 2), np.nan) if self.covariances is None
                   else self.covariances[rows[first]])
            out[int(tid)] = (fr, self.points_m[rows[first]], cov)
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
                           source="tracks", covariances=tr.covariance[:, :2, :2])
    if source == "tracks":
        raise CalibrationError(f"node {node.name} has no tracks")
    det = node.centroids
    if det is None or len(det) == 0:
        raise MissingStepError(f"node {node.name} has neither tracks nor centroids to calibrate "
                               "from", step="process")
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
    support: int = 0
    accepted: bool = False


@dataclass(frozen=True, kw_only=True, slots=True)
class TrackMatching:
    """Result of :func:`match_tracks`.

    calibration : the closed form on all accepted pairs (None on failure).
    pairs : accepted ``(track_a, track_b)`` pairs.
    lag_frames : node b's frame ``k + lag`` matches node a's frame ``k``.
    candidates : every scored hypothesis.
    lag_evidence : how the data decided a nonzero lag (kept: its evidence;
        not determined: lag 0 kept), None when lag 0 won outright.
    lag_ambiguous : the walk has a symmetry that no model can break: every
        lag within 2 frames of the chosen one, on both sides, fits within
        :data:`SYMMETRY_RMSE_RATIO` of its RMSE (a walk along a circle: a time
        shift is a turn about its centre), with poses more than 3 sigma away;
        the lag is not determined and the covariance was widened by their
        spread. (Next-frame lags alone fitting about as well is the flat bottom
        of the RMSE that the joint refinement's Doppler resolves: random walks
        show it with lags 2 frames away 13-33% worse.)
    """

    calibration: PairwiseCalibration | None
    pairs: tuple[tuple[int, int], ...]
    lag_frames: int
    candidates: tuple[TrackCandidate, ...]
    success: bool
    message: str
    lag_evidence: LagEvidence | None = None
    lag_ambiguous: bool = False


def _common(fa: NDArray, fb: NDArray, lag: int) -> tuple[NDArray, NDArray]:
    _, ia, ib = np.intersect1d(fa, fb - lag, assume_unique=True, return_indices=True)
    return ia, ib


#: Frame pairs compared at a time when the lags are found from the frame
#: differences (bounds the memory of a sparse frame span).
_DIFF_BLOCK = 1 << 22


def _overlapping_lags(ta, tb, max_lag_frames: int, need: int) -> list[int]:
    """The lags within ``+-max_lag_frames`` at which at least ``need`` frames
    of a's tracks meet frames of b's: a lag window wider than the
    recording costs no more than the recording (``max_lag_s=1e6`` on 200
    frames searches at most 400 lags, not 13 million)."""
    fa = np.unique(np.concatenate([f for f, _, _ in ta.values()]))
    fb = np.unique(np.concatenate([f for f, _, _ in tb.values()]))
    if not fa.size or not fb.size:
        return []
    lo = max(-int(max_lag_frames), int(fb[0]) - int(fa[-1]))
    hi = min(int(max_lag_frames), int(fb[-1]) - int(fa[0]))
    if lo > hi:
        return []
    if hi - lo + 1 <= 4 * (fa.size + fb.size):  # dense frames: every lag in the window
        return list(range(lo, hi + 1))
    # sparse frames (gaps): only the differences that occur, counted block by block
    counts: dict[int, int] = {}
    step = max(1, _DIFF_BLOCK // fb.size)
    for i in range(0, fa.size, step):
        with np.errstate(over="ignore"):  # a wrapped difference joins no frame: harmless
            d = fb[None, :] - fa[i:i + step, None]
        d = d[(d >= lo) & (d <= hi)]
        for lag, n in zip(*np.unique(d, return_counts=True)):
            counts[int(lag)] = counts.get(int(lag), 0) + int(n)
    return sorted(lag for lag, n in counts.items() if n >= need)


def _join(fa: NDArray, fb: NDArray, lag: int) -> tuple[NDArray, NDArray]:
    """All row pairs ``(i, j)`` with ``fa[i] == fb[j] - lag`` (many to many)."""
    order = np.argsort(fb, kind="stable")
    fb_sorted = fb[order] - lag
    lo = np.searchsorted(fb_sorted, fa, side="left")
    hi = np.searchsorted(fb_sorted, fa, side="right")
    counts = hi - lo
    ia = np.repeat(np.arange(fa.size), counts)
    offsets = np.arange(ia.size) - np.repeat(np.cumsum(counts) - counts, counts)
    ib = order[np.repeat(lo, counts) + offsets]
    return ia, ib


def _misalignment(pose: NDArray, za: NDArray, zb: NDArray) -> NDArray:
    """(n, 2) ``z_a - (p + R(phi) z_b)`` per row."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    x = pose[0] + c * zb[:, 0] - s * zb[:, 1]
    y = pose[1] + s * zb[:, 0] + c * zb[:, 1]
    return np.stack([za[:, 0] - x, za[:, 1] - y], axis=-1)


def _gate_d2(pose: NDArray, r: NDArray, ca: NDArray, cb: NDArray) -> NDArray:
    """``r^T (C_a + R C_b R^T)^{-1} r`` per row (2x2 entries written out:
    a three-operand einsum took most of the matching's time with many short
    tracks)."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    bxx, bxy, byy = cb[:, 0, 0], 0.5 * (cb[:, 0, 1] + cb[:, 1, 0]), cb[:, 1, 1]
    a = ca[:, 0, 0] + c * c * bxx - 2 * c * s * bxy + s * s * byy
    b = 0.5 * (ca[:, 0, 1] + ca[:, 1, 0]) + c * s * (bxx - byy) + (c * c - s * s) * bxy
    d = ca[:, 1, 1] + s * s * bxx + 2 * c * s * bxy + c * c * byy
    det = a * d - b * b
    with np.errstate(divide="ignore", invalid="ignore"):
        d2 = (d * r[:, 0] ** 2 - 2 * b * r[:, 0] * r[:, 1] + a * r[:, 1] ** 2) / det
    return np.where(det > 0, d2, np.inf)


class _Pool:
    """Every row of every track of both nodes, and their pairings at each lag."""

    def __init__(self, ta, tb, lags, inlier_gate_m, gate_probability):
        self.fa = np.concatenate([f for f, _, _ in ta.values()])
        self.za = np.concatenate([p for _, p, _ in ta.values()])
        self.ca = np.concatenate([c for _, _, c in ta.values()])
        self.ida = np.concatenate([np.full(f.size, t) for t, (f, _, _) in ta.items()])
        self.fb = np.concatenate([f for f, _, _ in tb.values()])
        self.zb = np.concatenate([p for _, p, _ in tb.values()])
        self.cb = np.concatenate([c for _, _, c in tb.values()])
        self.idb = np.concatenate([np.full(f.size, t) for t, (f, _, _) in tb.items()])
        self.joins = {lag: _join(self.fa, self.fb, lag) for lag in lags}
        # The rows of each lag's pairs gathered once (support() is called
        # for every candidate: thousands with many short tracks).
        self.rows = {lag: (self.za[ia], self.zb[ib], self.ca[ia], self.cb[ib])
                     for lag, (ia, ib) in self.joins.items()}
        self.gate = inlier_gate_m
        self.chi2_gate = (chi2_gate(gate_probability, 2) if not (
            np.isnan(self.ca).any() or np.isnan(self.cb).any()) else None)

    def support(self, pose, lag):
        """Row pairs at ``lag`` that ``pose`` aligns within the gate."""
        ia, ib = self.joins[lag]
        za, zb, ca, cb = self.rows[lag]
        r = _misalignment(pose, za, zb)
        if self.chi2_gate is None:
            inl = np.hypot(r[:, 0], r[:, 1]) < self.gate
        else:
            d2 = _gate_d2(pose, r, ca, cb)
            # A row whose covariances are singular (exact tracks: zero) has
            # no chi-square; the metric gate of tracks without covariances
            # decides it, not an infinite distance.
            inl = np.where(np.isinf(d2), np.hypot(r[:, 0], r[:, 1]) < self.gate,
                           d2 < self.chi2_gate)
        return ia[inl], ib[inl]


def _candidates(ta, tb, lags, pool, min_common_frames, min_spread_m) -> list[TrackCandidate]:
    """The closed form of every (track a, track b, lag) with enough common
    frames of a moving target, scored by its support."""
    cands: list[TrackCandidate] = []
    need = max(min_common_frames, 3)
    for ida, (fa, pa, _) in ta.items():
        for idb, (fb, pb, _) in tb.items():
            for lag in lags:
                # Overlap of the frame spans first (cheap: most pairs of
                # short tracks do not overlap at all).
                if min(fa[-1], fb[-1] - lag) - max(fa[0], fb[0] - lag) + 1 < need:
                    continue
                ia, ib = _common(fa, fb, lag)
                if ia.size < need:
                    continue
                za, zb = pa[ia], pb[ib]
                spread = min(np.sqrt(np.mean(np.sum((za - za.mean(0)) ** 2, 1))),
                             np.sqrt(np.mean(np.sum((zb - zb.mean(0)) ** 2, 1))))
                if spread < min_spread_m:
                    continue
                pose, j = closed_form_pose(za, zb)
                cands.append(TrackCandidate(track_a=ida, track_b=idb, lag_frames=lag,
                                            n_frames=int(ia.size),
                                            rmse_m=float(np.sqrt(j / ia.size)), pose=pose,
                                            support=int(pool.support(pose, lag)[0].size)))
    return cands


def _fit_lags(cands, lags, pool) -> dict[int, tuple[NDArray, NDArray, NDArray, float]]:
    """The best-supported hypothesis of each lag, refitted on its inliers:
    lag -> (pose, rows a, rows b, inlier RMSE)."""
    fits: dict[int, tuple[NDArray, NDArray, NDArray, float]] = {}
    for lag in lags:
        at_lag = [c for c in cands if c.lag_frames == lag]
        if not at_lag:
            continue
        best = max(at_lag, key=lambda c: (c.support, -c.rmse_m))
        fit = _refit(pool, best.pose, lag)
        if fit is not None:
            fits[lag] = fit
    return fits


def _refit(pool, pose, lag):
    """``pose`` refitted (twice) on the row pairs it supports at ``lag``:
    ``(pose, rows a, rows b, inlier RMSE)``, or None below 3 rows."""
    ia, ib = pool.support(pose, lag)
    for _ in range(2):
        if ia.size < 3:
            return None
        pose, _ = closed_form_pose(pool.za[ia], pool.zb[ib])
        ia, ib = pool.support(pose, lag)
    if ia.size < 3:
        return None
    pose, j = closed_form_pose(pool.za[ia], pool.zb[ib])
    return pose, ia, ib, float(np.sqrt(j / ia.size))


#: A nonzero lag is kept only when its fit beats lag 0's on the same track
#: pairs by at least this many standard errors (module doc).
LAG_EVIDENCE_Z = 3.0


def _same_track_rows(pool, pairs, lag) -> dict[tuple[int, int], int]:
    """(row of a, track of b) -> row of b at ``lag``, for the track pairs
    ``pairs`` ((n, 2) ids)."""
    ja, jb = pool.joins[lag]
    ids = np.stack([pool.ida[ja], pool.idb[jb]], axis=1)
    sel = (ids[:, None, :] == pairs[None]).all(-1).any(1)
    return {(int(a), int(pool.idb[b])): int(b) for a, b in zip(ja[sel], jb[sel])}


def lag_evidence(pool, fits, lag, base=0) -> tuple[float, NDArray | None]:
    """How strongly the data prefer ``lag`` to lag 0 (module doc): on the
    frames of the track pairs that ``lag``'s fit aligns, each lag's pose is
    fitted on the same rows of node a (paired with node b's frame ``k`` and
    ``k + lag``); the per-frame differences of their squared residuals
    (clipped at the gate) give ``z = mean / standard error``, the standard
    error corrected for their autocorrelation
    (:func:`autocorrelation_factor`). Returns ``(z, lag 0's pose on those
    rows)``; ``z`` NaN when fewer than 8 frames pair at both lags. ``base``:
    another lag in place of 0 (its pose returned)."""
    _, ia, ib, _ = fits[lag]
    pairs = np.unique(np.stack([pool.ida[ia], pool.idb[ib]], axis=1), axis=0)
    at0, atl = _same_track_rows(pool, pairs, base), _same_track_rows(pool, pairs, lag)
    keys = sorted(set(at0) & set(atl))
    if len(keys) < 8:
        return float("nan"), None
    ra = np.array([k[0] for k in keys])
    rb0, rbl = np.array([at0[k] for k in keys]), np.array([atl[k] for k in keys])
    z, p0, _ = paired_lag_evidence(pool.za[ra], pool.zb[rb0], pool.zb[rbl], pool.fa[ra],
                                   pool.gate)
    return -z, p0


def paired_lag_evidence(za, zb0, zbl, frames, gate_m) -> tuple[float, NDArray | None,
                                                                NDArray | None]:
    """How strongly lag 0 beats another lag on the same rows of node a:
    ``za`` (n, 2) paired with node b's ``zb0`` (its frame ``k``) and ``zbl``
    (frame ``k + lag``); each lag's pose fitted on the rows either aligns
    within ``gate_m`` (three passes), the per-row differences of their
    squared residuals (clipped at the gate) give ``z = mean / standard
    error``, the standard error corrected for their autocorrelation over
    ``frames``. Positive: the lag fits worse than lag 0. Returns ``(z, lag
    0's pose, the lag's pose)``; ``z`` NaN and poses None below 8 rows."""
    za, zb0, zbl = (np.asarray(a, dtype=float) for a in (za, zb0, zbl))
    frames = np.asarray(frames)
    gate2 = float(gate_m) ** 2
    keep = np.ones(za.shape[0], dtype=bool)
    if keep.sum() < 8:
        return float("nan"), None, None
    for _ in range(3):  # both poses on the rows either aligns within the gate
        p0, _ = closed_form_pose(za[keep], zb0[keep])
        pl, _ = closed_form_pose(za[keep], zbl[keep])
        with np.errstate(over="ignore", invalid="ignore"):  # a wild point: inf, clipped
            e0 = np.sum(_misalignment(p0, za, zb0) ** 2, axis=1)
            el = np.sum(_misalignment(pl, za, zbl) ** 2, axis=1)
        keep = (e0 < gate2) | (el < gate2)
        if keep.sum() < 8:
            return float("nan"), None, None
    d = (np.minimum(el, gate2) - np.minimum(e0, gate2))[keep]
    fr = frames[keep]
    order = np.argsort(fr, kind="stable")
    tau = autocorrelation_factor((d - d.mean())[order, None], fr[order])
    se = float(np.std(d, ddof=1)) * np.sqrt(tau / d.size)
    z = float(d.mean() / se) if se > 0 else (float("inf") if d.mean() > 0 else 0.0)
    return z, p0, pl


def _choose_lag(fits, lag_min_improvement) -> int:
    """Among the lags that explain (nearly) as many frames as the best, the
    one with the lowest inlier RMSE; lag 0 unless the data show a lag."""
    most = max(f[1].size for f in fits.values())
    lag = min((L for L in fits if fits[L][1].size >= 0.95 * most), key=lambda L: fits[L][3])
    if lag != 0 and 0 in fits:
        n0, r0 = fits[0][1].size, fits[0][3]
        nl, rl = fits[lag][1].size, fits[lag][3]
        if not (nl >= 0.95 * n0 and rl <= (1.0 - lag_min_improvement) * r0) and n0 >= 0.5 * nl:
            lag = 0  # the data do not show a lag: keep the nodes' own sync
    return lag


#: Lags up to 2 frames away on both sides within this ratio of the chosen
#: lag's RMSE: a symmetry of the walk (:attr:`TrackMatching.lag_ambiguous`).
SYMMETRY_RMSE_RATIO = 1.05


def _symmetric(fits, lag) -> bool:
    """Every lag within 2 frames of ``lag``, on both sides, fits about as
    well: the RMSE is flat, not the bottom of a valley (time-correlated
    errors flatten one side of a random walk's, never both)."""
    n, r = fits[lag][1].size, fits[lag][3]
    near = [lag + d for d in (-2, -1, 1, 2)]
    return all(L in fits and fits[L][1].size >= 0.95 * n
               and fits[L][3] <= SYMMETRY_RMSE_RATIO * r for L in near)


def _ambiguous_lags(fits, lag, lag_ambiguity) -> list[int]:
    """The other lags that explain about as many frames (95%) with an inlier
    RMSE within ``lag_ambiguity`` of the chosen lag's: the data do not tell
    them apart (a walk along a circle: a time shift is a turn about its
    centre, which the pose absorbs)."""
    n, r = fits[lag][1].size, fits[lag][3]
    return [L for L in fits if L != lag and fits[L][1].size >= 0.95 * n
            and fits[L][3] <= (1.0 + lag_ambiguity) * r]


def _widened(cal, lag, fits, ambiguous):
    """Lower the confidence of an ambiguous lag: add the spread of the poses
    of the competing lags (``d d^T`` per lag, body tangent) to the
    covariance when they differ from the chosen pose by more than 3 sigma."""
    cov = np.asarray(cal.covariance, dtype=float)
    extra = np.zeros((3, 3))
    for L in ambiguous:
        d = pose_tangent_error(fits[L][0], cal.pose)
        if d @ np.linalg.solve(cov, d) > 9.0:
            extra += np.outer(d, d)
    if not extra.any():
        return cal
    return replace(cal, covariance=cov + extra,
                   message=(f"{cal.message}; lag ambiguous (lags {sorted(ambiguous)} fit about as "
                            f"well with other poses): covariance widened by their spread"))


def _majority_rows(pool, lag, ia, ib):
    """Keep the inlier rows of track pairs with most of their common frames
    inliers (one target); two targets that cross contribute a few only."""
    ja, jb = pool.joins[lag]
    common_pairs, common_counts = np.unique(np.stack([pool.ida[ja], pool.idb[jb]], axis=1),
                                            axis=0, return_counts=True)
    common = {(int(a), int(b)): int(n) for (a, b), n in zip(common_pairs, common_counts)}
    if not ia.size:
        return ia, ib
    in_pairs, inverse, in_counts = np.unique(np.stack([pool.ida[ia], pool.idb[ib]], axis=1),
                                             axis=0, return_inverse=True, return_counts=True)
    need = np.array([common[(int(a), int(b))] for a, b in in_pairs])
    keep = (2 * in_counts >= need)[inverse.ravel()]
    return ia[keep], ib[keep]


def _failed(message, cands=()) -> TrackMatching:
    return TrackMatching(calibration=None, pairs=(), lag_frames=0, candidates=tuple(cands),
                         success=False, message=message)


#: Default lag window (s) and minimum overlap (s) of :func:`match_tracks`
#: when ``frame_period_s`` is given: 2 and 5 frames at 150 ms.


def _matched(pool, lag, ia, ib, cands, covariance, min_common_frames, min_spread_m,
             autocorrelation):
    """The closed form on the accepted rows, and the accepted track pairs."""
    order = np.argsort(pool.fa[ia], kind="stable")
    ia, ib = ia[order], ib[order]
    cal = closed_form_calibration(pool.za[ia], pool.zb[ib], covariance=covariance,
                                  min_common_frames=min_common_frames,
                                  min_spread_m=min_spread_m, frames=pool.fa[ia],
                                  autocorrelation=autocorrelation)
    pair_rows = np.stack([pool.ida[ia], pool.idb[ib]], axis=1)
    uniq, counts = np.unique(pair_rows, axis=0, return_counts=True)
    pairs = tuple((int(a), int(b)) for a, b in uniq[np.argsort(-counts, kind="stable")])
    accepted = set(pairs)
    cands = [replace(c, accepted=(c.lag_frames == lag and (c.track_a, c.track_b) in accepted))
             for c in cands]
    single = len(pairs) == 1
    cal = replace(
        cal, lag_frames=lag, track_a=pairs[0][0] if single else -1,
        track_b=pairs[0][1] if single else -1,
        message=(f"{len(pairs)} matched track pair(s) at lag {lag} frames, "
                 f"{ia.size} inlier frame pairs; {cal.message}"))
    return TrackMatching(calibration=cal, pairs=pairs, lag_frames=lag, candidates=tuple(cands),
                         success=True, message=cal.message)


def match_tracks(
    tracks_a: LocalTracks,
    tracks_b: LocalTracks,
    *,
    frame_period_s: float,
    options: MatchingOptions | None = None,
) -> TrackMatching:
    """Match two nodes' local tracks and calibrate b in a's frame (module doc).

    tracks_a, tracks_b : the two nodes' local tracks.
    frame_period_s : the frame period (s), which turns the thresholds in
        seconds into frames.
    options : the thresholds (:class:`MatchingOptions`; None: its defaults).

    Returns a :class:`TrackMatching`; ``success=False`` (no calibration) when
    no pair has enough common frames of a moving target, or the best pose
    leaves a track RMSE above ``options.max_rmse_m``.
    """
    o = MatchingOptions() if options is None else options
    if not isinstance(o, MatchingOptions):
        raise ValidationError(f"options must be a MatchingOptions, got {o!r}")
    max_lag_frames, min_common_frames = o.frame_counts(frame_period_s)
    min_spread_m, max_rmse_m = o.min_spread_m, o.max_rmse_m
    inlier_gate_m, gate_probability = o.inlier_gate_m, o.gate_probability
    ta, tb = tracks_a.split_rows(), tracks_b.split_rows()
    if not ta or not tb:
        return _failed(f"no pair of tracks: node a has {len(ta)} track(s), node b {len(tb)}")
    lags = _overlapping_lags(ta, tb, max_lag_frames, max(min_common_frames, 3))
    pool = _Pool(ta, tb, lags, inlier_gate_m, gate_probability)
    cands = _candidates(ta, tb, lags, pool, min_common_frames, min_spread_m)
    if not cands:
        return _failed(f"no pair of tracks shares >= {max(min_common_frames, 3)} frames of a "
                       f"moving target (spread >= {min_spread_m} m) within +-{max_lag_frames} "
                       f"frames of lag")
    fits = _fit_lags(cands, lags, pool)
    if not fits:
        best = min(cands, key=lambda c: c.rmse_m)
        gate = (f"inlier_gate_m={inlier_gate_m} m" if pool.chi2_gate is None
                else f"the chi-square gate (gate_probability={gate_probability})")
        return _failed(f"no pose aligns 3 frames within {gate}; the "
                       f"best track RMSE is {best.rmse_m:.3g} m", cands)
    lag = _choose_lag(fits, o.lag_min_improvement)
    lag, fits, evidence = _supported_lag(pool, fits, lag, max_lag_frames)
    _, ia, ib, rmse = fits[lag]
    if rmse > max_rmse_m:
        return _failed(f"no pair of tracks matches: the best track RMSE {rmse:.3g} m "
                       f"(lag {lag}) exceeds max_rmse_m={max_rmse_m}", cands)
    ambiguous = _ambiguous_lags(fits, lag, o.lag_ambiguity)
    ia, ib = _majority_rows(pool, lag, ia, ib)
    if ia.size < 3:
        return _failed("no track pair has a majority of its common frames aligned by one pose",
                       cands)
    matched = _matched(pool, lag, ia, ib, cands, o.covariance, min_common_frames, min_spread_m,
                       o.autocorrelation)
    cal = _widened(matched.calibration, lag, fits, ambiguous)
    widened = cal is not matched.calibration and _symmetric(fits, lag)
    return replace(matched, calibration=cal, message=cal.message, lag_evidence=evidence,
                   lag_ambiguous=widened)


def _supported_lag(pool, fits, lag, max_lag_frames):
    """``(lag, fits, evidence)``: a nonzero ``lag`` that the data do not
    determine becomes 0, refitted from the lag's own track pairs (a lag-0
    fit of other tracks may sit in another basin), and the
    :class:`~mmsnap_graph.data.calibration_facts.LagEvidence` says how it
    was decided (None for lag 0).
    Not determined: below :data:`LAG_EVIDENCE_Z` of :func:`lag_evidence`, or
    at the edge of the search window (``max_lag_frames``), where the fit is
    not seen to get worse beyond it: a time shift that a turn of the pose
    absorbs improves the RMSE a little with every frame (two walkers seen by
    synchronised radars at right angles: docs/validation/calibration.md, "Figures behind the estimators' rules").
    An edge lag that its inner neighbour fits better (``z < 0`` against
    it) hands over to the neighbour, tested the same way."""
    if lag == 0:
        return lag, fits, None
    z, pose0 = lag_evidence(pool, fits, lag)
    edge = abs(lag) >= max_lag_frames and lag - np.sign(lag) in pool.joins
    inner, z_inner = int(lag - np.sign(lag)), float("nan")
    if edge:  # a lag at the edge must beat its inner neighbour too
        z_inner = lag_evidence(pool, fits, lag, base=inner)[0]
        edge = not z_inner >= LAG_EVIDENCE_Z
    if edge and inner != 0 and fits.get(inner) is not None and z_inner < 0:
        # The inner neighbour fits better than the edge: the fit's best lag
        # lies inside the window, and the neighbour is tested against lag 0
        # (three nodes, S3 1.3 frames early: the edge lag 2 lost to lag 1 at
        # z = -5.2 and lag 0 was kept, S3's clock 195 ms off).
        return _supported_lag(pool, fits, inner, max_lag_frames)

    def said(outcome):
        return LagEvidence(lag_frames=int(lag), outcome=outcome, z=float(z),
                           evidence_z=LAG_EVIDENCE_Z, window_frames=int(max_lag_frames))

    if z >= LAG_EVIDENCE_Z and not edge:
        return lag, fits, said("determined")
    refit = None if pose0 is None else _refit(pool, pose0, 0)
    if refit is None:
        return lag, fits, said("untested")
    return 0, {**fits, 0: refit}, said("window_edge" if edge and z >= LAG_EVIDENCE_Z
                                      else "not_determined")
