"""The motion check of :func:`mmsnap_graph.fusion.recording.sequence.fuse_recording`:
robust fusion of a recording with its temporal context (docs/ROBUST.md).

One frame alone cannot always tell a ghost centroid (multipath, clutter) from
a detection: with three nodes, leaving out a node leaves two range circles
with two intersections, and a ghost range can pick the mirror point with
consistent residuals. A recording has neighbouring frames. After the per-frame
fusion (and its residual gate), :func:`apply_motion_check` tests every fused row
against the constant-velocity motion of the rows of the neighbouring frames
(:func:`factors.motion.cv_transition`, white acceleration of
:data:`MOTION_ACCEL_SIGMA_MPS2`):

1. **Confirm**: a successful row is *confirmed* when the successful rows of
   at least :data:`MOTION_MIN_SUPPORT` other frames within
   :data:`MOTION_WINDOW_FRAMES` frames, and of at least half of those frames
   that have one, predict its state within the chi-square gate (4 dof,
   :data:`MOTION_GATE_PROBABILITY`; the prediction's and the row's own
   covariances summed: a ghost's Doppler disagrees with the target's velocity
   even where its position agrees). Confirmed rows are kept as they are.
2. **Twice**: a successful one-node row that agrees with a prediction a row of
   more nodes of its frame takes (and with no other free one) counts that
   target twice: flagged.
3. **Predict**: each frame's predictions are the confirmed rows of the
   neighbouring frames carried to it (those of two nodes or more where there
   are any; the tightest of each group of agreeing predictions); a
   prediction a confirmed row of the frame agrees with is taken.
4. **Explain**: an unconfirmed one-node row is flagged (its cross-range
   velocity comes from the prior: a ghost can agree with a wide prediction).
   An unconfirmed row of more nodes that agrees with a free prediction is
   kept as it is; otherwise its hypotheses (the subsets of its nodes that
   leave out at most :data:`MOTION_MAX_LEFT_OUT`, started at each free
   prediction, so that the crossing of two circles near the prediction is
   found rather than its mirror) are fitted
   and the one with most nodes that passes the residual test
   (:func:`~mmsnap_graph.fusion.robust.residual_test_fails`) and agrees with
   the prediction is kept; the nodes it leaves out are ``rejected``.
5. **Flag**: a row no hypothesis explains is returned with ``success``
   False and a message saying why (a ghost, or a frame left ambiguous) when
   it is where a free prediction is, or when no other frame agrees with it at
   all; never as a confident wrong target. A row of two or more nodes away
   from every free prediction that some neighbouring frame agrees with (a
   second target without confirmed neighbours) keeps its per-frame result.

The estimate and covariance of a kept row are always the one-shot ones of the
measurements kept (no motion prior enters them: a tracker downstream may use
them as independent measurements).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from itertools import combinations
from typing import Callable

import numpy as np
from numpy.typing import NDArray

from factors.motion import cv_process_noise, cv_transition

from ..._validation import chi2_gate
from ...data.results import Status
from ...data.solution import FusionSolution
from ..robust import residual_test_fails
from .rows import FusedRows

__all__ = [
    "MOTION_WINDOW_FRAMES",
    "MOTION_MIN_SUPPORT",
    "MOTION_GATE_PROBABILITY",
    "MOTION_ACCEL_SIGMA_MPS2",
    "MOTION_FLAG_STATUS",
    "MOTION_CONTEXT_FRAMES",
    "MOTION_MAX_LEFT_OUT",
    "Refit",
    "apply_motion_check",
    "rows_near",
]

#: Frames on each side of a row whose rows may confirm or predict it.
MOTION_WINDOW_FRAMES = 3
#: Confirming frames a row needs (of the ``2 * MOTION_WINDOW_FRAMES`` around it).
MOTION_MIN_SUPPORT = 2
#: Probability of the chi-square (2 dof) gate on a predicted position.
MOTION_GATE_PROBABILITY = 0.999
#: White-acceleration sigma of the prediction (a walking human's). A sharper
#: turn or start leaves the rows on one side of it confirmed by the other
#: side (half of the frames around suffice, :func:`_confirmed`).
MOTION_ACCEL_SIGMA_MPS2 = 1.0
#: Nodes a hypothesis may leave out of a row (with more nodes the subsets
#: would grow as 2^N; two ghosts in one row of many nodes are rare).
MOTION_MAX_LEFT_OUT = 2
#: How far (frames) the check of a row looks: its neighbours' confirmation
#: looks ``MOTION_WINDOW_FRAMES`` further, and the one-node rows they
#: exclude as many again. A window fused with this many frames of context on
#: each side gives its own frames' rows as the whole recording does.
MOTION_CONTEXT_FRAMES = 3 * MOTION_WINDOW_FRAMES
#: The status of a row the motion check flags: its residuals with the motion
#: prediction fail the chi-square test for every subset of its nodes.
MOTION_FLAG_STATUS = Status.MOTION_INCONSISTENT

#: ``refit(rows (H,), observed (H, N), initial_state (H, 4))`` -> the
#: :class:`~mmsnap_graph.data.solution.FusionSolution` of the H hypotheses.
Refit = Callable[[NDArray, NDArray, NDArray], FusionSolution]


@dataclass(frozen=True, slots=True)
class _Predictions:
    """Predicted states of frames: ``frame (P,)``, ``state (P, 4)``, ``cov (P, 4, 4)``."""

    frame: NDArray
    state: NDArray
    cov: NDArray


def _carry(state: NDArray, cov: NDArray, steps: NDArray, frame_period_s: float,
           accel: float) -> tuple[NDArray, NDArray]:
    """States ``(M, 4)`` with covariances carried ``steps (M,)`` frames (either
    way): ``(state (M, 4), covariance (M, 4, 4))``."""
    out_x = np.empty_like(state)
    out_p = np.empty((state.shape[0], 4, 4))
    for s in np.unique(steps).tolist():
        m = steps == s
        f, ft, q = _transition(float(s) * frame_period_s, accel)
        out_x[m] = state[m] @ ft
        out_p[m] = f @ cov[m] @ ft + q
    return out_x, out_p


@lru_cache(maxsize=64)
def _transition(t: float, accel: float) -> tuple[NDArray, NDArray, NDArray]:
    """``(F, F^T, Q)`` of a carry over ``t`` seconds (the same few steps every
    frame), read-only."""
    f = cv_transition(t)
    out = (f, f.T, cv_process_noise(abs(t), accel))
    for a in out:
        a.setflags(write=False)
    return out


def _m2(d: NDArray, s: NDArray) -> NDArray:
    """``d^T s^-1 d`` of (M, 2) vectors and (M, 2, 2) covariances (inf if singular)."""
    det = s[:, 0, 0] * s[:, 1, 1] - s[:, 0, 1] * s[:, 1, 0]
    q = s[:, 1, 1] * d[:, 0] ** 2 - (s[:, 0, 1] + s[:, 1, 0]) * d[:, 0] * d[:, 1] \
        + s[:, 0, 0] * d[:, 1] ** 2
    with np.errstate(all="ignore"):
        m2 = q / det
    return np.where((det > 0) & np.isfinite(m2), m2, np.inf)


def _m4(d: NDArray, s: NDArray) -> NDArray:
    """``d^T s^-1 d`` of (M, 4) vectors and (M, 4, 4) covariances (inf where
    not finite or singular)."""
    out = np.full(d.shape[0], np.inf)
    good = np.all(np.isfinite(d), axis=1) & np.all(np.isfinite(s), axis=(1, 2))
    if good.any():
        try:
            sol = np.linalg.solve(s[good], d[good][..., None])[..., 0]
            out[good] = np.einsum("mi,mi->m", d[good], sol)
        except np.linalg.LinAlgError:  # one singular sum: row by row
            for k in np.flatnonzero(good):
                try:
                    out[k] = float(d[k] @ np.linalg.solve(s[k], d[k]))
                except np.linalg.LinAlgError:
                    pass
    return np.where(out >= 0, out, np.inf)


def _pairs(frame: NDArray, src: NDArray, dst: NDArray, window: int):
    """``(i, j, step)``: every source row ``src[i]`` and destination row
    ``dst[j]`` (row indices into ``frame``) with ``0 < |frame[dst] - frame[src]| <= window``;
    ``step = frame[dst] - frame[src]``."""
    order = np.argsort(frame[src], kind="stable")
    fs = frame[src][order]
    out_i, out_j = [], []
    for d in [d for k in range(1, window + 1) for d in (k, -k)]:
        target = frame[dst] - d  # source frame that is d frames before the destination
        lo = np.searchsorted(fs, target, "left")
        hi = np.searchsorted(fs, target, "right")
        n = hi - lo
        j = np.repeat(np.arange(dst.size), n)
        base = np.repeat(lo - np.concatenate([[0], np.cumsum(n)[:-1]]), n)
        out_i.append(order[base + np.arange(j.size)])
        out_j.append(j)
    i = np.concatenate(out_i) if out_i else np.zeros(0, np.int64)
    j = np.concatenate(out_j) if out_j else np.zeros(0, np.int64)
    return i, j, frame[dst][j] - frame[src][i]


def _pair_m2(rows, frame, src, dst, frame_period_s, accel):
    """``(i, j, m2)`` of the pairs of :func:`_pairs`: the squared distance
    (4 dof: a ghost's Doppler disagrees with the target's velocity) of the
    destination row's state to the source row's prediction."""
    i, j, step = _pairs(frame, src, dst, MOTION_WINDOW_FRAMES)
    x, p = _carry(rows.state[src[i]], rows.covariance[src[i]], step, frame_period_s, accel)
    return i, j, _m4(rows.state[dst[j]] - x, p + rows.covariance[dst[j]])


def _frames_per_row(j: NDArray, src_frame: NDArray, n: int) -> NDArray:
    """(n,) the distinct source frames of each destination ``j``."""
    if j.size == 0:
        return np.zeros(n, dtype=np.int64)
    # Each distinct (j, frame) once: one integer key per pair (a 1-D unique
    # is several times faster than the rows' unique).
    low = int(src_frame.min())
    span = int(src_frame.max()) - low + 1
    key = np.unique(j.astype(np.int64) * span + (src_frame.astype(np.int64) - low))
    return np.bincount(key // span, minlength=n)


def _confirmed(rows, frame, ok, frame_period_s, accel, gate, judged=None):
    """``(confirmed (K,), supported (K,))``: the successful rows that the
    successful rows of at least :data:`MOTION_MIN_SUPPORT` other frames, and
    of at least half of the other frames around that have one, agree with
    (the half: a row a ghost's Doppler spoilt still agrees with the far
    frames' loose predictions, not with the near ones); and those one other
    frame agrees with. ``judged`` (K,) bool: the rows to judge (None: all;
    the others are False in both, their neighbours still confirm)."""
    idx = np.flatnonzero(ok)
    out = np.zeros(frame.size, dtype=bool)
    dst = idx if judged is None else idx[judged[idx]]
    if dst.size == 0:
        return out, out.copy()
    i, j, m2 = _pair_m2(rows, frame, idx, dst, frame_period_s, accel)
    agree = m2 <= gate
    support = _frames_per_row(j[agree], frame[idx[i[agree]]], dst.size)
    available = _frames_per_row(j, frame[idx[i]], dst.size)
    out[dst[(support >= MOTION_MIN_SUPPORT) & (2 * support >= available)]] = True
    supported = np.zeros(frame.size, dtype=bool)
    supported[dst[support > 0]] = True
    return out, supported


def rows_near(frame: NDArray, decide: NDArray, frames: int) -> NDArray:
    """(K,) bool: the rows whose frame is at most ``frames`` from one of ``decide``."""
    d = np.unique(decide)
    return np.searchsorted(d, frame + frames, "right") > np.searchsorted(d, frame - frames,
                                                                           "left")


def _predictions(rows, frame, confirmed, frames_needed, frame_period_s, accel, gate,
                 n_kept, dedupe=True):
    """The confirmed rows carried to each frame of ``frames_needed``: those
    of two nodes or more, or where there are none, those of one node (a
    one-node row's prediction is wide across its line of sight); of the
    predictions of a frame that agree with each other, the tightest, unless
    ``dedupe`` is False."""
    src = np.flatnonzero(confirmed)
    fn = np.unique(frames_needed)
    if src.size == 0 or fn.size == 0:
        return _Predictions(np.zeros(0, np.int64), np.zeros((0, 4)), np.zeros((0, 4, 4)))
    i, j, step = _pairs(np.concatenate([frame, fn]), src, frame.size + np.arange(fn.size),
                        MOTION_WINDOW_FRAMES)
    multi = n_kept[src[i]] >= 2
    has_multi = np.bincount(j[multi], minlength=fn.size) > 0
    use = multi | ~has_multi[j]
    i, j, step = i[use], j[use], step[use]
    x, p = _carry(rows.state[src[i]], rows.covariance[src[i]], step, frame_period_s, accel)
    keep = np.full(i.size, not dedupe)
    order = np.lexsort((np.abs(step), np.trace(p[:, :2, :2], axis1=1, axis2=2), j))
    cuts = np.flatnonzero(np.diff(j[order])) + 1
    for cand in np.split(order, cuts) if dedupe else []:  # a frame's, tightest first
        kept: list[int] = []
        for c in cand:  # a few per frame
            if kept and np.any(_m4(x[kept] - x[c], p[kept] + p[c]) <= gate):
                continue
            kept.append(int(c))
        keep[kept] = True
    sel = np.flatnonzero(keep)
    sel = sel[np.argsort(j[sel], kind="stable")]  # by frame
    return _Predictions(fn[j[sel]], x[sel], p[sel])


def _subsets(observed: NDArray) -> list[NDArray]:
    """The subsets of the observed nodes that leave out at most
    :data:`MOTION_MAX_LEFT_OUT` of them (every non-empty one for three
    nodes), largest first, as masks."""
    nodes = np.flatnonzero(observed)
    out = []
    for size in range(nodes.size, max(0, nodes.size - MOTION_MAX_LEFT_OUT - 1), -1):
        for c in combinations(nodes.tolist(), size):
            m = np.zeros(observed.size, dtype=bool)
            m[list(c)] = True
            out.append(m)
    return out


def _agree(state: NDArray, cov: NDArray, preds: _Predictions, pi: NDArray) -> NDArray:
    """(R, P) squared Mahalanobis distances of row states to predictions ``pi``."""
    d = state[:, None] - preds.state[None, pi]
    s = cov[:, None] + preds.cov[None, pi]
    return _m4(d.reshape(-1, 4), s.reshape(-1, 4, 4)).reshape(d.shape[:2])


def _claim(rows, rs, confirmed, ok, preds, pi, gate) -> tuple[NDArray, list[int]]:
    """One frame's free predictions (mask over ``pi``) once its confirmed rows
    take those they agree with, then its unconfirmed successful rows kept as
    they are because they agree with a free one (greedy, closest first); and
    the rows still to explain."""
    free = np.ones(pi.size, dtype=bool)
    conf = rs[confirmed[rs]]
    if conf.size and pi.size:
        free &= ~np.any(_agree(rows.state[conf], rows.covariance[conf], preds, pi) <= gate, axis=0)
    todo = [int(r) for r in rs[~confirmed[rs]]]
    cand = [r for r in todo if ok[r]]
    if cand and free.any():
        m2 = _agree(rows.state[cand], rows.covariance[cand], preds, pi)
        m2[:, ~free] = np.inf
        for flat in np.argsort(m2, axis=None):
            a, b = np.unravel_index(flat, m2.shape)
            if not np.isfinite(m2[a, b]) or m2[a, b] > gate:
                break
            if free[b] and cand[a] in todo:
                free[b] = False
                todo.remove(cand[a])
    return free, todo


def _hypotheses(jobs, observed, valid, preds):
    """Every (row, prediction, subset) to fit: ``(row (H,), pred (H,), mask (H, N))``."""
    row_l, pred_l, mask_l = [], [], []
    for r, pis in jobs:
        for m in _subsets(observed[r] & valid[r]):
            for q in pis:
                row_l.append(r)
                pred_l.append(q)
                mask_l.append(m)
    n = observed.shape[1]
    return (np.asarray(row_l, dtype=np.int64), np.asarray(pred_l, dtype=np.int64),
            np.asarray(mask_l, dtype=bool).reshape(-1, n))


def _score(res, preds, hp, probability, gate):
    """``(passes (H,), score (H,))`` of fitted hypotheses: the fit converged,
    passes the residual test and agrees with its prediction; the score is the
    squared residuals plus the squared distance to the prediction."""
    ok = (np.asarray(res.status) == Status.OK) & np.all(np.isfinite(res.covariance), axis=(1, 2))
    cov = np.where(ok[:, None, None], res.covariance, np.eye(4))
    m2 = _m4(res.state - preds.state[hp], cov + preds.cov[hp])
    wr = np.asarray(res.whitened_residuals, dtype=float)
    passes = ok & ~residual_test_fails(wr, probability) & (m2 <= gate)
    return passes, np.nansum(wr ** 2, axis=(1, 2)) + m2


def _near(rows, r: int, preds: _Predictions, pis: NDArray, gate: float) -> bool:
    """Whether row ``r``'s position agrees (chi-square, 2 dof) with one of
    the predictions ``pis``."""
    d = rows.state[r, :2] - preds.state[pis, :2]
    s = rows.covariance[r, :2, :2] + preds.cov[pis, :2, :2]
    return bool(np.any(_m2(d, s) <= gate))


def _names(mask: NDArray, node_names) -> str:
    return ", ".join(str(node_names[n]) for n in np.flatnonzero(mask))


def _select(rows, observed, hr, hp, hm, res, passes, score, node_names) -> NDArray:
    """Keep, per row, the passing hypothesis of most nodes and lowest score,
    each prediction taken at most once (greedy); the rows explained."""
    order = np.lexsort((score, -hm.sum(axis=1)))
    used_row: set[int] = set()
    used_pred: set[int] = set()
    for h in order[passes[order]]:
        r, q = int(hr[h]), int(hp[h])
        if r in used_row or q in used_pred:
            continue
        used_row.add(r)
        used_pred.add(q)
        left = observed[r] & ~hm[h]
        rows.put([r], res[h], rejected=left[None], message="converged" + (
            f"; motion check: {_names(left, node_names)} left out" if left.any() else
            "; motion check: refitted from the predicted state"))
    return np.array(sorted(used_row), dtype=np.int64)


def _flag(rows: FusedRows, r: int, observed: NDArray, text: str) -> None:
    rows.flag(r, MOTION_FLAG_STATUS, f"motion check: {text}", rejected=observed[r])


_GHOST = ("no subset of its nodes agrees with the motion of a target in the neighbouring "
          "frames (a ghost, or a frame left ambiguous)")
_LONE = "a one-node detection that no neighbouring frame confirms (a ghost)"
_TWICE = "a one-node detection of the target of another row of this frame"


def _shared_frames(frame: NDArray, ok: NDArray, kept: NDArray) -> NDArray:
    """The frames with a successful one-node row and a successful row of more nodes."""
    n = kept.sum(axis=1)
    return np.intersect1d(frame[ok & (n == 1)], frame[ok & (n >= 2)])


def _twice(rows, frame, observed, shared, gate, preds_all, preds) -> list[int]:
    """Flag each successful one-node row of the frames ``shared`` that counts
    a target twice: it agrees with a prediction (``preds_all``, every
    confirmed row of the neighbouring frames carried) that a successful row
    of more nodes of its frame agrees with, and with none of the distinct
    predictions (``preds``) those rows leave free (a second target crossing
    the first). Its cross-range velocity comes from the prior, so it may
    agree with a prediction at a wrong position. Returns the rows flagged."""
    flagged = []
    for f in shared:
        rs = np.arange(*np.searchsorted(frame, [f, f + 1]))
        ok = rs[rows.status[rs] == Status.OK]
        n = (observed[ok] & ~rows.rejected[ok]).sum(axis=1)
        one, many = ok[n == 1], ok[n >= 2]
        pa = np.arange(*np.searchsorted(preds_all.frame, [f, f + 1]))
        if pa.size == 0 or one.size == 0 or many.size == 0:
            continue
        taken = np.any(_agree(rows.state[many], rows.covariance[many], preds_all, pa) <= gate,
                       axis=0)
        twice = np.any((_agree(rows.state[one], rows.covariance[one], preds_all, pa) <= gate)
                       & taken, axis=1)
        pi = np.arange(*np.searchsorted(preds.frame, [f, f + 1]))
        free = _free_after(rows, many, preds, pi, gate)
        for r in one[twice]:
            m2 = _agree(rows.state[[r]], rows.covariance[[r]], preds, pi)[0]
            best = np.flatnonzero(free & (m2 <= gate))
            if best.size:
                free[best[np.argmin(m2[best])]] = False  # a second target
            else:
                _flag(rows, int(r), observed, _TWICE)
                flagged.append(int(r))
    return flagged


def _free_after(rows, taking, preds, pi, gate) -> NDArray:
    """Mask over ``pi``: the predictions left once each row of ``taking``
    takes the one it agrees with best."""
    free = np.ones(pi.size, dtype=bool)
    if pi.size == 0:
        return free
    m2 = _agree(rows.state[taking], rows.covariance[taking], preds, pi)
    for a in np.argsort(m2.min(axis=1)):
        ok = np.flatnonzero(free & (m2[a] <= gate))
        if ok.size:
            free[ok[np.argmin(m2[a, ok])]] = False
    return free


def apply_motion_check(rows: FusedRows, frame: NDArray, observed: NDArray, valid: NDArray, *,
                       frame_period_s: float, refit: Refit, node_names,
                       residual_gate_probability: float,
                       decide: NDArray | None = None) -> NDArray:
    """Check every fused row of a recording against the motion of its
    neighbouring frames (module docstring); ``rows`` (the rows of
    :func:`~mmsnap_graph.fusion.recording.sequence.fuse_recording`) is updated
    through :meth:`FusedRows.put` (a row refitted) and :meth:`FusedRows.flag`
    (a row flagged).

    frame : (K,) the rows' frames, sorted. observed, valid : (K, N) bool, the
    nodes of each row and those whose measurement may be fitted.
    refit : fits hypotheses (:data:`Refit`). decide : the frames whose rows
    are refitted or flagged (None: every frame); the other rows are their
    context (a stream deciding one frame from those around it): the rows of
    a frame decided get what the check of every frame gives them. Returns the
    rows refitted.
    """
    gate = chi2_gate(MOTION_GATE_PROBABILITY, 4)
    accel = MOTION_ACCEL_SIGMA_MPS2
    ok = (rows.status == Status.OK) & np.all(np.isfinite(rows.covariance), axis=(1, 2))
    kept = observed & ~rows.rejected
    n_kept = kept.sum(axis=1)
    w = MOTION_WINDOW_FRAMES
    # Deciding some frames, the check needs: their rows' confirmation and the
    # rows that predict them (W frames around), those rows' one-node twins
    # (the first pass below), whose predictions come from W frames further;
    # the other rows are context. The rows of W frames around stay as the
    # whole check leaves them (the coverage check looks at them).
    confirmed, supported = _confirmed(rows, frame, ok, frame_period_s, accel, gate,
                                      None if decide is None else rows_near(frame, decide, 2 * w))
    # The one-node rows that count a target twice go first: they predict nothing.
    shared = _shared_frames(frame, ok, kept)
    if decide is not None:
        shared = np.intersect1d(shared, frame[rows_near(frame, decide, w)])
    twice = np.zeros(frame.size, dtype=bool)
    twice[_twice(rows, frame, observed, shared, gate,
                 _predictions(rows, frame, confirmed, shared, frame_period_s, accel, gate,
                              n_kept, False),
                 _predictions(rows, frame, confirmed, shared, frame_period_s, accel, gate,
                              n_kept))] = True
    ok &= rows.status == Status.OK
    confirmed &= ok
    todo_frames = np.unique(frame[~confirmed])
    if decide is not None:
        todo_frames = np.intersect1d(todo_frames, decide)
    preds = _predictions(rows, frame, confirmed, todo_frames, frame_period_s, accel,
                         gate, n_kept)
    jobs, lone = [], []
    for f in todo_frames:
        lo, hi = np.searchsorted(frame, [f, f + 1])
        rs = np.arange(lo, hi)
        rs = rs[~twice[rs]]  # flagged already
        pi = np.arange(*np.searchsorted(preds.frame, [f, f + 1]))
        # An unconfirmed one-node row is never kept: its cross-range velocity
        # comes from the prior, so a ghost can agree with a wide prediction.
        single = ok & (n_kept == 1) & ~confirmed
        lone.extend((int(r), _LONE) for r in rs[single[rs]])
        free, todo = _claim(rows, rs[~single[rs]], confirmed, ok, preds, pi, gate)
        for r in todo:
            if free.any():
                jobs.append((r, pi[free]))
            elif pi.size and ok[r] and not supported[r]:
                lone.append((r, _GHOST))
    hr, hp, hm = _hypotheses(jobs, observed, valid, preds)
    done = np.zeros(0, dtype=np.int64)
    if hr.size:
        res = refit(hr, hm, preds.state[hp])
        passes, score = _score(res, preds, hp, residual_gate_probability, gate)
        done = _select(rows, observed, hr, hp, hm, res, passes, score, node_names)
    explained = set(done.tolist())
    pos_gate = chi2_gate(MOTION_GATE_PROBABILITY, 2)
    for r, pis in jobs:
        # A row of two nodes or more no hypothesis explains is flagged when
        # it is where a free prediction is (a target's wrong estimate) or no
        # frame agrees with it; else it is a target with no confirmed
        # neighbours: kept. A row that failed already keeps its status.
        if r not in explained and ok[r] and (not supported[r]
                                             or _near(rows, r, preds, pis, pos_gate)):
            _flag(rows, r, observed, _GHOST)
    for r, text in lone:
        _flag(rows, r, observed, text)
    n_kept = (observed & ~rows.rejected).sum(axis=1)
    shared = _shared_frames(frame, rows.status == Status.OK, observed & ~rows.rejected)
    if decide is not None:
        shared = np.intersect1d(shared, decide)
    _twice(rows, frame, observed, shared, gate,
           _predictions(rows, frame, confirmed, shared, frame_period_s, accel, gate, n_kept,
                        False),
           _predictions(rows, frame, confirmed, shared, frame_period_s, accel, gate, n_kept))
    return done
