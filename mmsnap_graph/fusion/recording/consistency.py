"""The fused covariances checked against the data alone, without truth.

A user with no ground truth cannot compute a NEES. Two statistics of the
fused rows say the same from the data (:class:`ConsistencyMonitor`):

- **the central tracker's normalised innovations**: the person ids of the
  rows (the central tracker's, :class:`~mmsnap_graph.tracking.person_ids.PersonIds`,
  which every driver runs last) link the rows of one person over time; a
  constant-velocity Kalman filter over each person's rows (the prior of a
  MAP row taken out, as the tracker does) predicts each row's position, and
  ``nu^T (P_pred + R) nu`` (2 dof, ``R`` the row's position covariance)
  averages to about 2 when the covariances are right. Rows seen by one radar
  alone count like the others: this is the statistic that sees them.
- **the cross-node residuals**: a row fused from ``n >= 2`` nodes' kept
  measurements has ``3 n - 4`` degrees of freedom left, and twice its final
  cost over them (pooled over the rows) would be about 1 if the measurement
  errors were independent Gaussians. They are not (heavy tails, the body's
  reflection depth, the poses' own errors): good runs of the real model gave
  1.5 (five radars) to 2.8 (two). This statistic sees what the innovations
  cannot: an error that stays from frame to frame (a pose off, a sigma too
  small on a slow error). The checks before it leave out the rows that
  disagree most, so both statistics are of the rows kept.

The motion model (:data:`INNOVATION_SIGMA_A_MPS2`) and the errors'
correlation in time (it makes the innovations smaller) keep the mean
innovation below its ideal 2 on good runs. The bands are set from seeded
Monte Carlo runs of the real model over random layouts, at 20 fps and 150 ms
(``tools/random_layouts.py --scales 0.3,3``), where good runs (fused NEES
within 1.5x of its 4 dof) and the same runs fused with every sigma scaled
0.3x or 3x were told apart: over-confident when either statistic is above
its band (:data:`INNOVATION_BAND`, :data:`RESIDUAL_MAX`), under-confident
when the innovations are below theirs. A verdict needs
:data:`MIN_INNOVATIONS` innovations (or residual rows).

:func:`fused_consistency` checks a whole :class:`FusedSequence`; the monitor
takes the rows window by window (``fuse_file``, :meth:`ConsistencyMonitor.add`)
or frame by frame (``mmsnap replay``, :meth:`ConsistencyMonitor.add_rows`) in
frame order, in bounded memory: running sums of the statistics and one filter
per live track (a track unseen for :data:`MAX_GAP_S` is dropped).
:meth:`ConsistencyMonitor.new_verdict` gives a report only when the verdict
changed, for the streaming commands' periodic lines; every command says a
failed check with the same sentence, :attr:`ConsistencyReport.warning`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from factors.motion import cv_process_noise

from ..._floats4 import cholesky_4x4, cholesky_inverse_4x4
from ...data.results import FusedSequence
from ...tracking.central import cv_predict_floats, measurement_information_floats

__all__ = ["ConsistencyReport", "ConsistencyMonitor", "fused_consistency",
           "INNOVATION_BAND", "RESIDUAL_MAX", "MIN_INNOVATIONS", "INNOVATION_SIGMA_A_MPS2"]

#: The white acceleration (m/s^2 per axis) of the check's filter: a walker
#: turning in a room (the per-node EKF's 3.0; the central tracker's 1.0 is
#: for association and made good runs' innovations 1.7x their 2 dof).
INNOVATION_SIGMA_A_MPS2 = 3.0
#: Mean normalised innovation (2 dof) of consistent covariances: measured
#: 1.1-2.1 on good runs; the same runs with 0.3x sigmas 3.1-4.0, with 3x 0.3-0.8.
INNOVATION_BAND = (0.8, 2.6)
#: Largest pooled cross-node residual chi-square per dof of consistent
#: covariances: measured 1.5-2.8 on good runs, 3.5-4.9 with 0.3x sigmas.
RESIDUAL_MAX = 3.3
#: Innovations needed for a verdict (fewer: "not enough data").
MIN_INNOVATIONS = 30
#: A track's rows further apart than this (s) start its filter again.
MAX_GAP_S = 1.0


@dataclass(frozen=True, kw_only=True, slots=True)
class ConsistencyReport:
    """What :class:`ConsistencyMonitor` found.

    verdict : ``"consistent"``, ``"over-confident"`` (covariances too small
        for the data), ``"under-confident"`` (too large) or
        ``"not enough data"``.
    innovation_nis : mean normalised position innovation (2 dof), over
        ``n_innovations``; innovation_tail : the share above the chi-square
        99% point (9.21; 1% when consistent).
    residual_ratio : pooled ``2 cost / (3 n - 4)`` over ``n_residual_rows``
        rows of two or more nodes (NaN without any).
    reasons : why the verdict is not "consistent" (empty when it is).
    """

    verdict: str
    innovation_nis: float
    innovation_tail: float
    n_innovations: int
    residual_ratio: float
    n_residual_rows: int
    reasons: tuple = ()

    @property
    def warning(self) -> str | None:
        """The loud sentence of a failed self-check (None when it passed or
        could not judge); each command prints it after its name."""
        if self.consistent is not False:
            return None
        return (f"warning: the fused covariances are {self.verdict} for this recording's "
                f"data: " + "; ".join(self.reasons) + ". Check the sigmas (--sigmas, mmsnap "
                "noise) and the calibration; downstream trackers take these covariances at "
                "face value")

    @property
    def consistent(self) -> bool | None:
        """True, False, or None without enough data."""
        return None if self.verdict == "not enough data" else self.verdict == "consistent"

    def to_dict(self) -> dict:
        def num(v):
            return None if not math.isfinite(v) else float(v)
        return {"verdict": self.verdict, "consistent": self.consistent,
                "innovation_nis": num(self.innovation_nis), "innovation_dof": 2,
                "innovation_band": list(INNOVATION_BAND),
                "innovation_tail": num(self.innovation_tail),
                "residual_max": RESIDUAL_MAX,
                "n_innovations": self.n_innovations,
                "residual_ratio": num(self.residual_ratio),
                "n_residual_rows": self.n_residual_rows, "reasons": list(self.reasons)}

    def text(self) -> str:
        """One line for a person."""
        nis = "-" if not self.n_innovations else f"{self.innovation_nis:.2f}"
        res = "-" if not self.n_residual_rows else f"{self.residual_ratio:.2f}"
        return (f"covariance self-check (no truth): {self.verdict}; mean normalised "
                f"innovation {nis} over {self.n_innovations} rows (2 dof; consistent "
                f"{INNOVATION_BAND[0]:g}-{INNOVATION_BAND[1]:g}); cross-node residual "
                f"chi-square {res} per dof over {self.n_residual_rows} rows (consistent <= "
                f"{RESIDUAL_MAX:g})")


@dataclass(slots=True)
class _Filter:
    """A track's filter: state (4 floats), covariance (16, row-major), last frame."""

    x: list
    p: list
    frame: int


def _symmetric(a: list) -> list:
    return [0.5 * (a[4 * i + j] + a[4 * j + i]) for i in range(4) for j in range(4)]


@dataclass
class ConsistencyMonitor:
    """Accumulates the statistics of :class:`ConsistencyReport` over fused
    rows given in frame order (:meth:`add`), then :meth:`report`. The
    filters' 4x4 algebra is done in plain floats (a row at a time: numpy's
    per-call cost would be most of the work)."""

    sigma_a_mps2: float = INNOVATION_SIGMA_A_MPS2
    _filters: dict = field(default_factory=dict)
    _nis_n: int = 0
    _nis_sum: float = 0.0
    _nis_tail: int = 0
    _last_frame: int | None = None
    _said: str | None = None
    _res_chi2: float = 0.0
    _res_dof: int = 0
    _res_rows: int = 0
    _q: dict = field(default_factory=dict)

    def add(self, fused: FusedSequence) -> None:
        """The rows of ``fused`` (after the last rows added)."""
        kept = np.asarray(fused.observed, dtype=bool)
        if fused.rejected is not None:
            kept = kept & ~np.asarray(fused.rejected, dtype=bool)
        prior = None if fused.prior_mean is None else (fused.prior_mean, fused.prior_sigmas)
        self.add_rows(fused.frame, fused.state, fused.covariance, success=fused.success,
                      track_id=fused.track_id, n_kept=kept.sum(axis=1),
                      final_cost=fused.final_cost, frame_period_s=fused.frame_period_s,
                      prior=prior)

    def add_rows(self, frame, state, covariance, *, success=None, track_id=None,
                 n_kept=None, final_cost=None, frame_period_s: float | None = None,
                 prior=None) -> None:
        """Fused rows as arrays, after the last rows added: ``frame`` (R,),
        ``state`` (R, 4), ``covariance`` (R, 4, 4); ``success`` (R,) bool
        (default: every row); ``track_id`` (R,) the central tracker's person
        of each row (-1: none; None: no innovations); ``n_kept`` (R,) the
        nodes kept and ``final_cost`` (R,) (None: no cross-node residuals);
        ``prior`` ``(mean (4,), sigmas (4,))`` of MAP rows (None: ML)."""
        frame = np.asarray(frame, dtype=np.int64).reshape(-1)
        cov = np.asarray(covariance, dtype=float).reshape(-1, 4, 4)
        ok = np.all(np.isfinite(cov), axis=(1, 2))
        if success is not None:
            ok &= np.asarray(success, dtype=bool)
        if n_kept is not None and final_cost is not None:
            n = np.asarray(n_kept, dtype=np.int64)
            cost = np.asarray(final_cost, dtype=float)
            res = ok & (n >= 2) & np.isfinite(cost)
            self._res_chi2 += float(np.sum(2.0 * cost[res]))
            self._res_dof += int(np.sum(3 * n[res] - 4))
            self._res_rows += int(res.sum())
        if track_id is None or frame.size == 0:
            return
        period = float(frame_period_s or 0.15)
        tid = np.asarray(track_id)
        order = np.argsort(frame, kind="stable")
        rows = order[(ok & (tid >= 0))[order]]
        prior = (None, None) if prior is None else (
            np.asarray(prior[0], dtype=float).tolist(),
            (1.0 / np.asarray(prior[1], dtype=float) ** 2).tolist())
        step = self._step
        for track, f, z, r in zip(tid[rows].tolist(), frame[rows].tolist(),
                                  np.asarray(state, dtype=float).reshape(-1, 4)[rows].tolist(),
                                  cov[rows].reshape(-1, 16).tolist()):
            step(track, f, z, r, prior, period)
        last = int(frame.max())
        if self._last_frame is None or last > self._last_frame:
            self._last_frame = last
            # Bounded memory: a track unseen for longer than MAX_GAP_S starts
            # again anyway, so its filter goes.
            horizon = last - MAX_GAP_S / period
            for t in [t for t, flt in self._filters.items() if flt.frame < horizon]:
                del self._filters[t]

    def add_update(self, update, frame: int, *, frame_period_s: float, prior=None) -> None:
        """The groups of one :class:`~mmsnap_graph.fusion.stream.frame_stream.StreamUpdate`
        (``mmsnap replay``, ``mmsnap live``) at frame number ``frame``;
        ``prior`` the stream's :class:`~mmsnap_graph.data.noise.GaussianPrior` (None: ML)."""
        if update.person_id is None or len(update) == 0:
            return
        members = np.asarray(update.members)
        kept = (members >= 0) & ~np.asarray(update.rejected, dtype=bool)
        self.add_rows(np.full(len(update), int(frame)), update.state, update.covariance,
                      success=update.success, track_id=update.person_id,
                      n_kept=kept.sum(axis=1), final_cost=update.final_cost,
                      frame_period_s=frame_period_s,
                      prior=None if prior is None else (prior.mean, prior.sigmas))

    def new_verdict(self) -> ConsistencyReport | None:
        """The report when its verdict differs from the one this method last
        gave (the first verdict once there is enough data), else None: what
        a streaming command prints now and then."""
        report = self.report()
        if report.verdict == "not enough data" or report.verdict == self._said:
            return None
        self._said = report.verdict
        return report

    def _step(self, track, frame, z, r, prior, period) -> None:
        """One row: the innovation of its track's prediction, then the update
        in information form (the row's measurement information, its prior
        taken out); a new track, a gap or a failed update starts again."""
        lam, eta = measurement_information_floats(z, _symmetric(r), *prior)
        f = self._filters.get(track)
        if f is not None and 0 < (frame - f.frame) * period <= MAX_GAP_S:
            dt = (frame - f.frame) * period
            q = self._q.get(dt)
            if q is None:
                q = self._q[dt] = cv_process_noise(dt, self.sigma_a_mps2).ravel().tolist()
            x, p = cv_predict_floats(f.x, f.p, dt, q)
            dx, dy = z[0] - x[0], z[1] - x[1]
            a, b, c, d = p[0] + r[0], p[1] + r[1], p[4] + r[4], p[5] + r[5]
            det = a * d - b * c
            if det != 0.0:  # nu^T S^-1 nu of the 2x2 position innovation
                nis = (d * dx * dx - (b + c) * dx * dy + a * dy * dy) / det
                self._nis_n += 1
                self._nis_sum += nis
                self._nis_tail += nis > 9.21
                lo = cholesky_4x4(p)
                if lo is not None:
                    info = cholesky_inverse_4x4(lo)
                    lo = cholesky_4x4([u + v for u, v in zip(info, lam)])
                if lo is not None:
                    p = cholesky_inverse_4x4(lo)  # exactly symmetric
                    h = [sum(info[4 * i + j] * x[j] for j in range(4)) + eta[i]
                         for i in range(4)]
                    x = [sum(p[4 * i + j] * h[j] for j in range(4)) for i in range(4)]
                    if all(math.isfinite(v) for v in p):
                        self._filters[track] = _Filter(x, p, frame)
                        return
        p0 = list(r)
        p0[10], p0[15] = max(p0[10], 1.0), max(p0[15], 1.0)
        self._filters[track] = _Filter(list(z), p0, frame)

    def report(self) -> ConsistencyReport:
        n_nis = self._nis_n
        mean = self._nis_sum / n_nis if n_nis else float("nan")
        tail = self._nis_tail / n_nis if n_nis else float("nan")
        ratio = self._res_chi2 / self._res_dof if self._res_dof > 0 else float("nan")
        reasons = []
        judged_nis = n_nis >= MIN_INNOVATIONS
        judged_res = self._res_rows >= MIN_INNOVATIONS
        if judged_nis and mean > INNOVATION_BAND[1]:
            reasons.append(f"the positions move between frames {math.sqrt(mean / 2):.1f}x more "
                           "than their covariances allow (mean normalised innovation "
                           f"{mean:.2f} > {INNOVATION_BAND[1]:g}, {tail:.0%} beyond the 99% "
                           "point)")
        if judged_res and ratio > RESIDUAL_MAX:
            reasons.append(f"the nodes disagree more than the measurement sigmas allow "
                           f"(cross-node residual chi-square per dof {ratio:.2f} > "
                           f"{RESIDUAL_MAX:g})")
        if reasons:
            verdict = "over-confident"
        elif judged_nis and mean < INNOVATION_BAND[0]:
            verdict = "under-confident"
            reasons.append("the positions move between frames less than their covariances say "
                           f"(mean normalised innovation {mean:.2f} < {INNOVATION_BAND[0]:g}): "
                           "covariances too large")
        elif judged_nis or judged_res:
            verdict = "consistent"
        else:
            verdict = "not enough data"
        return ConsistencyReport(verdict=verdict, innovation_nis=mean, innovation_tail=tail,
                                 n_innovations=n_nis, residual_ratio=ratio,
                                 n_residual_rows=self._res_rows, reasons=tuple(reasons))


def fused_consistency(fused: FusedSequence, *,
                      sigma_a_mps2: float = INNOVATION_SIGMA_A_MPS2) -> ConsistencyReport:
    """:class:`ConsistencyReport` of a whole fused sequence (its rows need
    their person ids, ``track_id``, for the innovations)."""
    monitor = ConsistencyMonitor(sigma_a_mps2=sigma_a_mps2)
    monitor.add(fused)
    return monitor.report()
