"""A calibration refined while the radars run, and a moved radar noticed and
re-calibrated alone (``mmsnap live --refine``, docs/LIVE.md, "Refining the
calibration live").

:class:`OnlineRefinement` is given each fused frame's centroids (board ->
``(K, 3)`` rows ``(range_m, omega_rad, doppler_mps)``), frame after frame,
and returns the :class:`PoseUpdate` records of what changed:

- **windows** (reason ``"window"``): every ``window_s`` of frames, that
  window is calibrated on its own as a windowed calibration calibrates each
  of its windows (:func:`~mmsnap_graph.calibration.network.calibrate_with_joint`
  on the centroids and each node's EKF tracks of them: track matching, pose
  graph, joint graph, the long-run covariance) and its pose block kept
  (:func:`~.joint.windowed.window_posterior`); the last ``max_windows``
  are combined in information form (:func:`~.joint.windowed.combine_windows`,
  the poses are static) into the poses, covariances and clock offsets
  published. A window nobody walked through (or whose solve failed) is
  left out and counted (``skipped``), and so is one whose pose of a node is
  further from the node's current pose than both covariances allow
  (:data:`WINDOW_GATE`: a short or straight walk solved wrongly; a radar
  that moved is the monitor's to notice). Memory is bounded: one window's
  frames and ``max_windows`` pose blocks.
- **a moved radar** (reasons ``"change"``, then ``"recalibrated"``): the
  frames with one target (live: one fused target, its nodes' rows) go to the
  :class:`~.monitor.decalibration.DecalibrationMonitor` (in blocks of
  ``monitor_block`` frames); when it declares a change of node ``X`` and
  then re-calibrates it from the frames after the change, ``X``'s pose
  becomes the monitor's and ``X`` is marginalised out of the windows kept
  (their rows and columns of ``X`` removed: they are of its old pose), so the
  next windows re-estimate ``X`` from the frames after the move while every
  other node keeps what the earlier windows gave it. The window being
  collected restarts at the change. A moved reference (three or more
  nodes) moves the frame every window is expressed in: every window kept is
  dropped.

Poses are in the frame of the poses given (the stored calibration's): a
window's calibration, in its reference node's frame, is placed by the
reference's current pose. The clock offsets are estimated and published,
not applied to anything here.
"""

from __future__ import annotations

import dataclasses
from collections import deque
from typing import Mapping

import gtsam
import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..data.calibration import RecordingCalibration
from ..data.calibration_facts import WindowsCombined
from ..data.noise import MeasurementNoise
from ..data.recording import Detections, NodeData, Recording
from ..errors import CalibrationError, ValidationError
from .._validation import check_count, chi2_gate, positive_scalar
from .joint.windowed import WindowPosterior, combine_windows, window_posterior
from .monitor.decalibration import DEFAULT_POSE_SIGMAS, DecalibrationMonitor
from .network import calibrate_with_joint
from .online_defaults import REFINE_MAX_WINDOWS, REFINE_WINDOW_S
from .poses import pose_array, to_pose2
from ..tracking.ekf import EkfConfig, track_centroids

__all__ = ["REFINE_WINDOW_S", "REFINE_MAX_WINDOWS", "WINDOW_GATE", "PoseUpdate", "OnlineRefinement",
           "without_node"]

#: A window whose pose of a node is further than this squared Mahalanobis
#: distance (chi-square 3, probability 1e-6 when both covariances hold) from
#: the node's current pose is left out (:meth:`OnlineRefinement._disagrees`).
WINDOW_GATE = chi2_gate(1.0 - 1e-6, 3)


@dataclasses.dataclass(frozen=True, slots=True)
class PoseUpdate:
    """What changed at ``frame`` (``time_s``): ``reason`` ``"window"`` (a
    window combined), ``"change"`` (the monitor declared that ``nodes[0]``
    moved; the poses are not changed yet) or ``"recalibrated"`` (its new
    pose); ``nodes`` the nodes whose pose changed (or moved); ``poses``,
    ``covariances`` (body tangent), ``time_offset_s``: every node's after
    the update; ``message``: one line for a person."""

    frame: int
    time_s: float
    reason: str
    nodes: tuple
    poses: Mapping
    covariances: Mapping
    time_offset_s: Mapping
    message: str

    def to_json(self) -> dict:
        """A JSON-ready record: ``{"type": "calibration", "frame", "time_s",
        "reason", "nodes", "poses": {name: [x_m, y_m, phi_rad]},
        "time_offset_s": {name: s}, "message"}``."""
        return {"type": "calibration", "frame": int(self.frame), "time_s": float(self.time_s),
                "reason": self.reason, "nodes": list(self.nodes),
                "poses": {n: [float(v) for v in p] for n, p in self.poses.items()},
                "time_offset_s": {n: (float(v) if np.isfinite(v) else None)
                                  for n, v in self.time_offset_s.items()},
                "message": self.message}


def without_node(post: WindowPosterior, node: str) -> WindowPosterior:
    """``post`` with ``node`` marginalised out: its pose and clock offset
    rows and columns removed (a Gaussian's marginal)."""
    keep = [i for i, lab in enumerate(post.labels) if not (len(lab) > 1 and lab[1] == node)]
    ix = np.ix_(keep, keep)
    return dataclasses.replace(
        post, labels=tuple(post.labels[i] for i in keep), random=post.random[ix].copy(),
        model=post.model[ix].copy(), depth=post.depth[keep].copy(),
        offsets={n: v for n, v in post.offsets.items() if n != node},
        widening={n: v for n, v in post.widening.items() if n != node})


def _one_target_rows(names, centroids: Mapping) -> NDArray:
    """(N, 3): each node's one centroid, NaN where it has none or several
    (the monitor follows one target)."""
    z = np.full((len(names), 3), np.nan)
    for i, n in enumerate(names):
        rows = centroids.get(n)
        if rows is not None and len(rows) == 1:
            z[i] = np.asarray(rows, dtype=float).reshape(3)
    return z


class OnlineRefinement:
    """The refinement of ``node_poses`` (name -> (3,), node order, the first
    the reference) frame by frame (module doc).

    covariances : name -> (3, 3) the stored calibration's (body tangent;
        None: the monitor's default sigmas). noise : the centroids' noise
        (the monitor's whitening). frame_period_s : the frames' period.
    window_s, max_windows : the windows (:data:`REFINE_WINDOW_S`,
        :data:`REFINE_MAX_WINDOWS`). monitor : watch for a moved radar.
    monitor_options : the monitor's (``threshold``, ``windows_s``,
        ``recalibration_s``, ``min_frames``). joint : the windows'
        :class:`~.joint.options.JointOptions` (None: the recording's default).
    """

    def __init__(self, node_poses: Mapping[str, ArrayLike], *, frame_period_s: float,
                 covariances: Mapping[str, ArrayLike] | None = None,
                 noise: MeasurementNoise = MeasurementNoise(),
                 window_s: float = REFINE_WINDOW_S, max_windows: int = REFINE_MAX_WINDOWS,
                 monitor: bool = True, monitor_options: Mapping | None = None,
                 monitor_block: int = 20, joint=None) -> None:
        self.names = tuple(node_poses)
        if len(self.names) < 2:
            raise ValidationError(f"node_poses: a refinement needs at least 2 nodes, got "
                                  f"{list(self.names)}")
        self.period = positive_scalar(frame_period_s, "frame_period_s")
        window_s = positive_scalar(window_s, "window_s (--refine-window-s)")
        self.window_frames = max(int(round(window_s / self.period)), 1)
        if self.window_frames < 20:
            raise ValidationError(f"window_s={window_s!r} (--refine-window-s) is "
                                  f"{self.window_frames} frames of {self.period:g} s: a window "
                                  "needs at least 20 frames")
        self.max_windows = check_count(max_windows, "max_windows", 1)
        self.monitor_block = check_count(monitor_block, "monitor_block", 1)
        self.joint = joint
        self._ekf = EkfConfig(frame_period_s=self.period)
        self.poses = {n: np.asarray(p, dtype=float).copy() for n, p in node_poses.items()}
        eye = np.full((3, 3), np.nan)
        self.covariances = {n: (eye if covariances is None or covariances.get(n) is None
                                else np.asarray(covariances[n], float).copy())
                            for n in self.names}
        self.offsets = {n: (0.0 if n == self.names[0] else float("nan")) for n in self.names}
        self.offset_variances = {n: (0.0 if n == self.names[0] else float("nan"))
                                 for n in self.names}
        self.monitor = None
        if monitor:
            self.monitor = DecalibrationMonitor(self.poses, noise=noise,
                                                node_covariances=covariances,
                                                frame_period_s=self.period,
                                                **dict(monitor_options or {}))
        self._posteriors: deque[WindowPosterior] = deque(maxlen=self.max_windows)
        self._reference: str | None = None      # the windows' reference node
        self._window: list = []                 # (frame, {name: rows}) of the window
        self._block: list = []                  # (time_s, (N, 3)) for the monitor
        self.windows = self.combined = 0
        self.skipped: list[str] = []
        self.frame = -1

    # ------------------------------------------------------------------
    def add(self, frame: int, centroids: Mapping[str, ArrayLike],
            one_target: Mapping[str, ArrayLike] | None = None) -> list[PoseUpdate]:
        """One fused frame's centroids (frames in increasing order; a frame
        left out had no centroid); the updates it completes. ``one_target``:
        name -> (3,) the rows of the frame's one fused target, what the
        monitor is given ({}: no single target; None: each node's only
        centroid, where it has one)."""
        frame = int(frame)
        self.frame = frame
        out = []
        rows = {n: np.asarray(z, dtype=float).reshape(-1, 3) for n, z in centroids.items()
                if n in self.poses and len(z)}
        if rows:
            self._window.append((frame, rows))
        if self.monitor is not None:
            single = rows if one_target is None else {n: np.reshape(z, (1, 3))
                                                      for n, z in one_target.items()}
            self._block.append((frame * self.period, _one_target_rows(self.names, single)))
            if len(self._block) >= self.monitor_block:
                out += self._watch()
        if self._window and frame - self._window[0][0] + 1 >= self.window_frames:
            out += self._close_window()
        return out

    def finish(self) -> list[PoseUpdate]:
        """The frames still held given to the monitor (the window being
        collected is not calibrated: it is shorter than a window)."""
        return self._watch() if self._block else []

    # ------------------------------------------------------------------
    def _watch(self) -> list[PoseUpdate]:
        times = np.array([t for t, _ in self._block])
        z = np.stack([r for _, r in self._block])
        self._block.clear()
        out = []
        for upd in self.monitor.update_frames(z, times):
            frame = int(round(upd.time_s / self.period))
            if upd.change is not None:
                c = upd.change
                start = int(round(c.time_s / self.period))
                self._window = [(f, r) for f, r in self._window if f >= start]
                out.append(self._update(frame, "change", (c.node,),
                                        f"{c.node} moved at {c.time_s:.1f} s (statistic "
                                        f"{c.statistic:.0f}); re-calibrating it"))
            rc = upd.recalibration
            if rc is not None and rc.fit.success:
                self.poses[rc.node] = np.asarray(rc.fit.pose, float).copy()
                self.covariances[rc.node] = np.asarray(rc.fit.covariance, float).copy()
                self._forget(rc.node)
                out.append(self._update(frame, "recalibrated", (rc.node,),
                                        f"{rc.node} re-calibrated from {rc.n_frames} frames: "
                                        f"pose {np.round(self.poses[rc.node], 4).tolist()}"))
        return out

    def _forget(self, node: str) -> None:
        """The windows kept without ``node`` (all of them for the reference)."""
        if node == self._reference:
            self._posteriors.clear()
            self._reference = None
            return
        kept = [without_node(p, node) for p in self._posteriors]
        self._posteriors = deque((p for p in kept if p.labels), maxlen=self.max_windows)

    def _recording(self) -> Recording:
        first = self._window[0][0]
        nodes = {}
        for n in self.names:
            parts = [(f - first, r[n]) for f, r in self._window if n in r]
            if parts:
                z = np.concatenate([r for _, r in parts])
                f = np.concatenate([np.full(len(r), k, np.int64) for k, r in parts])
                det = Detections(frame=f, range_m=z[:, 0], omega_rad=z[:, 1],
                                 doppler_mps=z[:, 2])
            else:
                det = Detections.empty()
            # Each node's EKF tracks (what mmsnap process gives offline): a
            # sparse cloud clusters into several centroids a frame, which the
            # track matching of centroids refuses.
            nodes[n] = NodeData(name=n, pose=None, centroids=det,
                                tracks=track_centroids(det, self._ekf) if len(det) else None)
        return Recording(frame_period_s=self.period, nodes=nodes)

    def _close_window(self) -> list[PoseUpdate]:
        first, last = self._window[0][0], self._window[-1][0]
        rec = self._recording()
        self._window.clear()
        self.windows += 1
        why = ""
        try:
            cal, jc = calibrate_with_joint(rec, source="auto", joint=self.joint,
                                           noise_estimate=False)
        except CalibrationError as exc:
            why = str(exc).splitlines()[0]
        else:
            if not cal.success or jc is None:
                why = cal.status.message if not cal.success else "the joint graph did not run"
            elif self._reference not in (None, cal.reference):
                why = f"its reference is {cal.reference}, the windows' {self._reference}"
        if not why:
            post = window_posterior(cal, jc, range_prior=(None if self.joint is None else
                                                             self.joint.range_offset_prior_m))
            if not all(np.all(np.isfinite(r)) and np.all(np.linalg.eigvalsh(0.5 * (r + r.T)) > 0)
                       for r in (post.random, post.model)):   # the combination inverts both
                why = "its pose covariance is not positive definite"
            else:
                why = self._disagrees(post, cal.reference)
        if why:
            self.skipped.append(f"frames {first}-{last}: {why}")
            return []
        self._reference = cal.reference
        self._posteriors.append(post)
        return [self._combine(last)]

    def _disagrees(self, post: WindowPosterior, ref: str) -> str:
        """Why a window's poses cannot be the current ones refined ("" when
        they can): a node whose pose is further from its current one than
        the window's covariance and the current one's allow (the chi-square
        gate :data:`WINDOW_GATE`; a node without a covariance: the monitor's
        :data:`~.monitor.decalibration.DEFAULT_POSE_SIGMAS`). A window that
        solved a short or straight walk wrongly is left out; a radar that
        moved is the monitor's to notice."""
        anchor = to_pose2(self.poses[ref])
        depth = post.rms**2 * post.depth @ post.depth.T if post.depth.size else 0.0
        total = post.random + depth
        for n in post.poses:
            if ("pose", n, 0) not in post.labels or n == ref:
                continue
            idx = [post.labels.index(("pose", n, k)) for k in range(3)]
            current = anchor.between(to_pose2(self.poses[n]))
            e = gtsam.Pose2.Logmap(current.between(to_pose2(post.poses[n])))
            c = self.covariances[n]
            if not np.all(np.isfinite(c)):
                c = np.diag(np.square(DEFAULT_POSE_SIGMAS))
            d2 = float(e @ np.linalg.solve(total[np.ix_(idx, idx)] + c, e))
            if d2 > WINDOW_GATE:
                return (f"{n}'s pose is {np.hypot(e[0], e[1]):.3f} m, {np.rad2deg(e[2]):.2f} "
                        f"deg from its current one (squared Mahalanobis distance {d2:.0f} > "
                        f"{WINDOW_GATE:.1f})")
        return ""

    def _combine(self, frame: int) -> PoseUpdate:
        comb = combine_windows(list(self._posteriors))
        self.combined += 1
        ref = self._reference
        anchor = to_pose2(self.poses[ref])
        changed = []
        for n, p in comb.poses().items():
            self.poses[n] = pose_array(anchor.compose(to_pose2(p)))
            self.covariances[n] = comb.block(n)
            changed.append(n)
        for lab in comb.labels:
            if lab[0] == "offset":
                i = comb.labels.index(lab)
                self.offsets[lab[1]] = float(comb.estimate[i])
                self.offset_variances[lab[1]] = float(comb.covariance[i, i])
        return self._update(frame, "window", tuple(changed),
                            f"window {self.windows} combined ({len(self._posteriors)} kept, "
                            f"{len(self.skipped)} skipped so far; spread factor "
                            f"{comb.spread_factor:.2f})")

    def _update(self, frame, reason, nodes, message) -> PoseUpdate:
        return PoseUpdate(frame=frame, time_s=frame * self.period, reason=reason,
                          nodes=tuple(nodes), poses={n: p.copy() for n, p in self.poses.items()},
                          covariances={n: c.copy() for n, c in self.covariances.items()},
                          time_offset_s=dict(self.offsets), message=message)

    def calibration(self) -> RecordingCalibration:
        """The current poses as a calibration (for the calibration JSON):
        the reference the stored one's first node, the covariances of the
        nodes refined or re-calibrated (NaN where neither happened yet and
        none was given)."""
        fact = WindowsCombined(window_s=self.window_frames * self.period,
                               n_windows=self.windows, n_combined=len(self._posteriors),
                               skipped=tuple(self.skipped[-10:]))
        ref = self.names[0]
        return RecordingCalibration(
            reference=ref, node_names=self.names,
            poses={n: p.copy() for n, p in self.poses.items()},
            covariances={n: (np.zeros((3, 3)) if n == ref else c.copy())
                         for n, c in self.covariances.items()},
            lag_frames={n: 0 for n in self.names}, method="joint", source="centroids",
            facts=(fact,), time_offset_s=dict(self.offsets),
            time_offset_variances=dict(self.offset_variances))

