"""Calibration of a long recording in bounded memory: window by window,
the windows' pose posteriors combined in information form.

The poses (and clock offsets, and an estimated range offset) are static,
the target's states are not shared between windows of minutes: given the
poses, the windows' data are independent, so each window is calibrated on
its own (:func:`~mmsnap_graph.calibration.network.calibrate_with_joint`: track
matching, pose graph, joint graph, the long-run covariance) from the frames
read out of the file (:class:`~mmsnap_graph.io.chunks.DetectionWindows`),
and only its pose block is kept: the estimate ``y_i`` (the poses as the
body-tangent step from the first window's), the graph's marginal ``S_i^-1`` (``model``: the
inverse of the window's information on the block, the target states
eliminated), the covariance ``R_i`` of its random part (the long-run
covariance: errors correlated in time within its bandwidth, seconds, not
minutes) and the columns ``M_i`` of the considered reflection depth
(:class:`~.covariance.BlockCovariance`). The combination:

- the estimate is the batch solve's: the windows share only the static
  parameters, so at the batch optimum each window's gradient is ``S_i (x -
  y_i)`` to first order and ``x = (sum S_i)^-1 sum S_i y_i``, ``A_i =
  (sum S_i)^-1 S_i`` its share of window ``i``. Weighting by the long-run
  ``R_i^-1`` instead is another estimator, not the batch's: a long-run
  covariance is a noisy estimate (about ``3 T / (2 L)`` degrees of
  freedom, 18 for 40 s of a walker) and its widening differs per window
  and direction, so its weights turn the combination away from the batch
  (the shared fall-detection recording in 2 windows of 42 s: S2 0.099 m,
  +1.93 deg off the tape against the batch's 0.059 m, -0.16 deg; weighted
  by ``S_i``: 0.054 m, -0.32 deg; docs/validation/calibration.md, "Long
  recordings");
- its random part is the windows' long-run covariances carried through
  those shares, ``P = sum A_i R_i A_i^T`` (what the batch's long-run
  covariance is over the windows' frames);
- a prior that every window's graph holds (the range offset's, when it
  is estimated) is the recording's once: ``n - 1`` copies of it are taken
  off the information, the score and the middle of ``P``;
- the reflection depth is the same person's in every window: it does not
  average down. Its columns combine as ``M = sum A_i M_i`` and add
  ``s^2 M M^T`` (not ``sum A_i M_i M_i^T A_i^T``, which would shrink it
  like noise);
- the lag cover of an ambiguous lag (``LagNotDetermined``) is a shift of
  the whole recording as well: each window's widening ``D_i`` combines as
  ``(sum A_i D_i^1/2)(...)^T``;
- the windows' spread: the generalised least-squares residual of the
  stacked window estimates under their joint covariance, the random parts
  (independent between windows) *and* the shared depth and lag covers
  (the same depth moves windows of different geometry differently: that
  is in the reported ``s^2 M M^T`` already, not a disagreement),
  ``chi2`` over ``sum P_i - P`` degrees of freedom. When it exceeds them
  beyond two standard errors, ``P`` is widened by ``chi2 / dof`` (the
  windows disagree more than they say: an error that lasts longer than
  the bandwidth). Left out of the spread test, the depth widened the
  fall-detection windows x5.6 on top of the depth's own term.

The noise at the calibrated poses (``RecordingCalibration.noise``, what
``mmsnap fuse`` weighs by) is the first combined window's: minutes of data
identify it, and it is half of a window's time at 10 nodes.

A window that cannot be calibrated alone (nobody walking, no track pair
matched, a failed solve, a status other than OK, a covariance not
positive definite) joins its frames to the next window's, which is
calibrated over both: a few seconds of two radars seeing a walker are not
enough alone but count with the next window's (the fall-detection
recording in windows of 21 s: S2 0.060 m off the tape, 0.096 m with the
window left out). When the joined window fails too, or the last window
fails, it is left out and named in the
:class:`~mmsnap_graph.data.calibration_facts.WindowsCombined` fact.
Peak memory is one window's calibration, two windows' where one joins the
next (the window, not the recording, sets it); the time is the windows'
sum, so about linear in the recording.

:func:`window_frames_for` is the policy of when to calibrate by windows:
``mmsnap calibrate`` and the library use it alike.
"""

from __future__ import annotations

import dataclasses
from typing import Callable

import gtsam
import numpy as np
from numpy.typing import NDArray

from ...data.calibration import RecordingCalibration
from ...data.calibration_facts import CalibrationStatus, WindowsCombined
from ...errors import CalibrationError, ValidationError
from ..network import calibrate_with_joint, joint_options_for
from ..poses import pose_array, to_pose2

__all__ = ["WINDOW_S", "WINDOWED_ABOVE_S", "window_frames_for", "WindowPosterior",
           "window_posterior", "combine_windows", "calibrate_windowed"]

#: The window of a windowed calibration (s), unless given: long enough
#: that a window's pose estimate is Gaussian (thousands of frames of a
#: walker) and its long-run covariance has hundreds of degrees of freedom,
#: short enough that one window's graph stays about 150 MB for 10 nodes.
WINDOW_S = 600.0
#: A recording spanning more than this (s) is calibrated by windows of
#: :data:`WINDOW_S` unless a window is given (the batch's memory grows
#: linearly: 710 MB for an hour of 10 nodes).
WINDOWED_ABOVE_S = 1200.0


def window_frames_for(span_frames: int, frame_period_s: float,
                      window_s: float | None = None) -> int | None:
    """The window (frames) to calibrate a recording of ``span_frames``
    frames by, or None for one batch solve: ``window_s`` given, its frames
    (None when the recording fits in one window; ``inf``: never); else
    :data:`WINDOW_S` when the recording spans more than
    :data:`WINDOWED_ABOVE_S`."""
    period = float(frame_period_s)
    if window_s is None:
        if span_frames * period <= WINDOWED_ABOVE_S:
            return None
        window_s = WINDOW_S
    if not isinstance(window_s, bool) and window_s == float("inf"):
        return None
    if isinstance(window_s, bool) or not np.isfinite(window_s) or window_s <= 0:
        raise ValidationError(f"window_s={window_s!r} (--window-s) must be a number of seconds "
                              f"> 0")
    frames = max(int(round(float(window_s) / period)), 1)
    if frames < 20:
        raise ValidationError(f"window_s={window_s!r} (--window-s) is {frames} frames of "
                              f"{period:g} s: a window needs at least 20 frames")
    return None if span_frames <= frames else frames


@dataclasses.dataclass(frozen=True, slots=True)
class WindowPosterior:
    """One window's pose block, what :func:`combine_windows` needs.

    labels : the block's parameters: ``("pose", name, 0..2)``, ``("offset",
        name)``, ``("range",)``. poses : name -> (3,) the window's poses;
    offsets : name -> clock offset (s); range_offset_m (NaN: not estimated).
    random, model : (P, P) the covariance without the considered depth,
        and the graph's marginal. depth : (P, C) the considered depth's
        columns (C = 0 without), named by ``depth_columns``; rms its
        root mean square (m). widening : name -> (3, 3) the lag cover
        added to the node's pose covariance. range_prior : ``(mean,
        sigma)`` (m) of the range offset's prior in the window's graph
        (None: no prior, or the range offset not estimated).
    """

    labels: tuple
    poses: dict
    offsets: dict
    range_offset_m: float
    random: NDArray
    model: NDArray
    depth: NDArray
    depth_columns: tuple
    rms: float
    widening: dict
    range_prior: tuple | None = None


def _psd(m: NDArray) -> NDArray:
    w, v = np.linalg.eigh(0.5 * (m + m.T))
    return (v * np.maximum(w, 0.0)) @ v.T


def _sqrt_psd(m: NDArray) -> NDArray:
    w, v = np.linalg.eigh(0.5 * (m + m.T))
    return (v * np.sqrt(np.maximum(w, 0.0))) @ v.T


def window_posterior(cal: RecordingCalibration, joint, *,
                     range_prior: tuple | None = None) -> WindowPosterior:
    """The pose block of one window's calibration ``cal`` and the joint
    graph's result ``joint`` it came from
    (:func:`~mmsnap_graph.calibration.network.calibrate_with_joint`);
    ``range_prior``: the range offset's prior ``(mean, sigma)`` of the
    options it was calibrated with (``JointOptions.range_offset_prior_m``),
    kept only when the block estimates the range offset."""
    others = [n for n in cal.node_names if n in cal.poses and n != cal.reference]
    block = joint.pose_block
    if block is not None:
        labels = []
        for key in dict.fromkeys(block.order):  # a pose's 3 columns share a key
            labels += ([(*key, j) for j in range(3)] if key[0] == "pose" else [key])
        random = block.covariance if block.random is None else block.random
        depth = (np.zeros((len(labels), 0)) if block.depth_response is None
                 else np.asarray(block.depth_response))
        cols, rms, model = block.depth_columns, block.range_offset_rms, block.model
        base = {n: block.node(n) for n in others}
    else:  # the graph's marginals: the poses' joint covariance, the offsets' variances
        timed = [n for n in others if np.isfinite(joint.time_offset_variances.get(n, np.nan))]
        labels = [("pose", n, j) for n in joint.joint_order for j in range(3)] + \
                 [("offset", n) for n in timed]
        random = np.zeros((len(labels), len(labels)))
        p = 3 * len(joint.joint_order)
        random[:p, :p] = joint.joint_covariance
        for i, n in enumerate(timed):
            random[p + i, p + i] = joint.time_offset_variances[n]
        model, depth, cols, rms = random, np.zeros((len(labels), 0)), (), 0.0
        base = {n: joint.covariances[n] for n in others}
    widening = {n: _psd(np.asarray(cal.covariances[n]) - base[n]) for n in others}
    return WindowPosterior(
        labels=tuple(labels), poses={n: np.asarray(cal.poses[n], float) for n in cal.poses},
        offsets={n: float(cal.time_offset_s[n]) for n in others if n in cal.time_offset_s},
        range_offset_m=float(cal.range_offset_m), random=np.asarray(random, float),
        model=np.asarray(model, float), depth=depth, depth_columns=tuple(cols),
        rms=float(rms), widening=widening,
        range_prior=(None if range_prior is None or ("range",) not in labels
                     else (float(range_prior[0]), float(range_prior[1]))))


def _vector(w: WindowPosterior, base: dict) -> NDArray:
    """The window's estimate: poses as body-tangent steps from ``base``."""
    steps = {n: gtsam.Pose2.Logmap(to_pose2(base[n]).between(to_pose2(p)))
             for n, p in w.poses.items() if n in base}
    out = []
    for lab in w.labels:
        if lab[0] == "pose":
            out.append(steps[lab[1]][lab[2]])
        elif lab[0] == "offset":
            out.append(w.offsets[lab[1]])
        else:
            out.append(w.range_offset_m)
    return np.asarray(out, float)


@dataclasses.dataclass(frozen=True, slots=True)
class Combined:
    """:func:`combine_windows`' result: ``labels``, the combined estimate
    (poses as steps from ``base``), its reported covariance and its
    graph-marginal ``model``, and the spread test."""

    labels: tuple
    base: dict
    estimate: NDArray
    covariance: NDArray
    model: NDArray
    spread_chi2: float
    spread_dof: int
    spread_factor: float

    def poses(self) -> dict:
        out = {}
        for n, b in self.base.items():
            idx = [self.labels.index(("pose", n, j)) for j in range(3)]
            out[n] = pose_array(to_pose2(b).compose(gtsam.Pose2.Expmap(self.estimate[idx])))
        return out

    def block(self, n: str, cov: NDArray | None = None) -> NDArray:
        idx = [self.labels.index(("pose", n, j)) for j in range(3)]
        c = self.covariance if cov is None else cov
        return c[np.ix_(idx, idx)].copy()


def _stack_columns(w: WindowPosterior, cols: tuple) -> tuple[NDArray, NDArray]:
    """The window's depth columns on the union ``cols`` (P_i, C) and its
    lag cover's root (P_i, P_i)."""
    depth = np.zeros((len(w.labels), len(cols)))
    if w.depth.size:
        depth[:, [cols.index(c) for c in w.depth_columns]] = w.depth
    lag = np.zeros((len(w.labels), len(w.labels)))
    for n, dn in w.widening.items():
        if ("pose", n, 0) in w.labels:
            j = [w.labels.index(("pose", n, k)) for k in range(3)]
            lag[np.ix_(j, j)] = _sqrt_psd(dn)
    return depth, lag


def _spread(parts, p: int, rms: float) -> tuple[float, int]:
    """The windows' spread (module doc): the generalised least-squares
    residual of the stacked estimates, ``chi2`` and its degrees of
    freedom. ``parts``: per window ``(idx, y, random, depth, lag)``."""
    n = sum(len(idx) for idx, *_ in parts)
    lift, ys, cov = np.zeros((n, p)), np.zeros(n), np.zeros((n, n))
    shared = np.zeros((n, parts[0][3].shape[1] + p))
    o = 0
    for idx, y, random, depth, lag in parts:
        k = len(idx)
        rows = slice(o, o + k)
        lift[o + np.arange(k), idx] = 1.0
        ys[rows] = y
        cov[rows, rows] = random
        shared[rows, :depth.shape[1]] = rms * depth
        shared[rows, depth.shape[1] + idx] = lag   # a lag shift of parameter j: column j
        o += k
    cov += shared @ shared.T
    white = np.linalg.solve(cov, np.column_stack([lift, ys]))
    x = np.linalg.solve(lift.T @ white[:, :p], lift.T @ white[:, p])
    r = ys - lift @ x
    return float(r @ np.linalg.solve(cov, r)), int(n - p)


def combine_windows(windows: list[WindowPosterior]) -> Combined:
    """The windows' pose posteriors combined (module doc)."""
    if not windows:
        raise CalibrationError("no window could be calibrated: nothing to combine")
    base = dict(windows[0].poses)
    labels = tuple(dict.fromkeys(lab for w in windows for lab in w.labels))
    cols = tuple(dict.fromkeys(c for w in windows for c in w.depth_columns))
    p = len(labels)
    info, score, middle = np.zeros((p, p)), np.zeros(p), np.zeros((p, p))
    parts = []
    for w in windows:
        idx = np.array([labels.index(lab) for lab in w.labels])
        y = _vector(w, base)
        random = 0.5 * (w.random + w.random.T)
        h = np.linalg.inv(0.5 * (w.model + w.model.T))   # the window's information
        info[np.ix_(idx, idx)] += h
        score[idx] += h @ y
        middle[np.ix_(idx, idx)] += h @ random @ h
        parts.append((idx, y, random, *_stack_columns(w, cols)))
    priors = [w.range_prior for w in windows if w.range_prior is not None]
    if len(priors) > 1:   # the recording's prior once, not once per window
        i = labels.index(("range",))
        for mean, sigma in priors[1:]:
            info[i, i] -= sigma**-2
            score[i] -= mean / sigma**2
            middle[i, i] -= sigma**-2
    model = np.linalg.inv(info)
    est = model @ score
    cov = _psd(model @ _psd(middle) @ model)
    rms = max((w.rms for w in windows), default=0.0)
    chi2, dof = _spread(parts, p, rms)
    factor = 1.0
    if dof > 0 and chi2 / dof > 1.0 + 2.0 * np.sqrt(2.0 / dof):
        factor = chi2 / dof
    depth = np.zeros((p, len(cols)))
    lag_root = np.zeros((p, p))
    for w, (idx, _, _, d_cols, d_lag) in zip(windows, parts):
        h = np.linalg.inv(0.5 * (w.model + w.model.T))
        a = model[:, idx] @ h   # (P, P_i): the window's share of the estimate
        depth += a @ d_cols
        lag_root[:, idx] += a @ d_lag   # columns: the parameters the shift is of
    total = factor * cov + rms**2 * depth @ depth.T + lag_root @ lag_root.T
    return Combined(labels=labels, base={n: b for n, b in base.items()
                                         if ("pose", n, 0) in labels},
                    estimate=est, covariance=0.5 * (total + total.T),
                    model=0.5 * (model + model.T), spread_chi2=chi2, spread_dof=dof,
                    spread_factor=factor)


def _result(first: RecordingCalibration, comb: Combined, fact: WindowsCombined,
            node_names) -> RecordingCalibration:
    """The combined calibration as a RecordingCalibration: the first
    combined window's edges, lags, noise and facts, the combined poses,
    covariances and offsets."""
    ref = first.reference
    poses = {ref: np.zeros(3), **comb.poses()}
    others = [n for n in node_names if n in poses and n != ref]
    covs = {ref: np.zeros((3, 3)), **{n: comb.block(n) for n in others}}
    model = {ref: np.zeros((3, 3)), **{n: comb.block(n, comb.model) for n in others}}
    idx = [comb.labels.index(("pose", n, j)) for n in others for j in range(3)]
    offsets, variances = {ref: 0.0}, {ref: 0.0}
    for n in others:
        if ("offset", n) in comb.labels:
            i = comb.labels.index(("offset", n))
            offsets[n], variances[n] = float(comb.estimate[i]), float(comb.covariance[i, i])
        else:
            offsets[n] = float(first.time_offset_s.get(n, np.nan))
            variances[n] = float(first.time_offset_variances.get(n, np.nan))
    rng, rng_var = float("nan"), float("nan")
    if ("range",) in comb.labels:
        i = comb.labels.index(("range",))
        rng, rng_var = float(comb.estimate[i]), float(comb.covariance[i, i])
    return dataclasses.replace(
        first, poses=poses, covariances=covs, model_covariances=model,
        unreachable=tuple(n for n in node_names if n not in poses),
        joint_covariance=comb.covariance[np.ix_(idx, idx)].copy(), joint_order=tuple(others),
        time_offset_s=offsets, time_offset_variances=variances,
        range_offset_m=rng, range_offset_variance=rng_var, facts=(fact, *first.facts))


def _unusable(post: WindowPosterior) -> str:
    """Why a window's pose block cannot be combined ("" when it can): a
    covariance that is not finite and positive definite."""
    for r, what in ((post.random, "pose covariance"), (post.model, "graph marginal")):
        if not np.all(np.isfinite(r)) or not np.all(np.isfinite(post.depth)):
            return f"its {what} is not finite"
        try:
            np.linalg.cholesky(0.5 * (r + r.T))
        except np.linalg.LinAlgError:
            return f"its {what} is not positive definite"
    return ""


def _spans(index, window_frames: int) -> list[tuple[int, int]]:
    """The windows' frame ranges; a last one shorter than half a window
    joins the one before it (a few frames at the end are no calibration)."""
    spans = list(index.windows(window_frames))
    if len(spans) >= 2 and spans[-1][1] - spans[-1][0] < window_frames / 2 \
            and spans[-1][0] == spans[-2][1]:
        spans[-2:] = [(spans[-2][0], spans[-1][1])]
    return spans


def calibrate_windowed(windows, window_frames: int, *,
                       source: str = "auto", method: str = "auto", noise=None, matching=None,
                       joint=None, on_window: Callable | None = None) -> RecordingCalibration:
    """Calibrate a recording file window by window, each of
    ``window_frames`` frames (:func:`window_frames_for`), reading one
    window's centroids (and tracks) at a time (module doc): ``windows`` is
    the file's :class:`~mmsnap_graph.io.chunks.DetectionWindows` of its
    centroids (:func:`~mmsnap_graph.io.chunks.open_detection_windows`).

    source, method, noise, matching, joint : as
    :func:`~mmsnap_graph.calibration.calibrate_recording`, for every window
    (a window holds the centroids and, unless ``source="centroids"``, the
    EKF tracks of its frames; ``method="pose_graph"`` is refused: the windows combine the joint
    graph's pose blocks). on_window : called with ``(start_frame,
    stop_frame, calibration or None, why)`` after each window.
    Returns the combined :class:`RecordingCalibration`, whose facts start
    with a :class:`~mmsnap_graph.data.calibration_facts.WindowsCombined`;
    :class:`CalibrationError` when no window could be calibrated.
    """
    if method == "pose_graph":
        raise ValidationError("method='pose_graph' cannot be calibrated by windows: the "
                              "windows combine the joint graph's poses (use a single solve)")
    index = windows
    if index.source != "centroids":
        raise ValidationError(f"the windows must be of the centroids, got {index.source!r}")
    posts, first, skipped, n = [], None, [], 0
    spans = _spans(index, int(window_frames))
    carry = None   # the start of a window that could not be calibrated alone
    for k, (start, stop) in enumerate(spans):
        n += 1
        lo = start if carry is None else carry
        rec, _ = index.read(lo, stop, tracks=source != "centroids")
        options = joint_options_for(rec) if joint is None else joint
        post = None
        try:
            cal, jc = calibrate_with_joint(
                rec, source=source, method=method, noise=noise, matching=matching,
                joint=options, noise_estimate=first is None)
        except CalibrationError as exc:
            why = str(exc).splitlines()[0]
            cal, jc = None, None
        else:
            why = ("" if cal.success and jc is not None else
                   cal.status.message if not cal.success else "the joint graph did not run")
        if not why:
            if first is not None and cal.reference != first.reference:
                raise CalibrationError(f"window {lo}-{stop - 1} has reference "
                                       f"{cal.reference}, the first {first.reference}")
            post = window_posterior(cal, jc, range_prior=options.range_offset_prior_m)
            why = _unusable(post)
        if why and carry is None and k + 1 < len(spans):
            carry = start   # its frames join the next window (at most two windows' frames)
            why = f"{why} (its frames join the next window's)"
        elif why:
            skipped.append(f"frames {lo}-{stop - 1}: {why}")
            carry = None
        else:
            first = cal if first is None else first
            posts.append(post)
            carry = None
        if on_window is not None:
            on_window(lo, stop, None if why else cal, why)
        del rec, cal, jc, post
    if not posts:
        raise CalibrationError(f"no window of {window_frames} frames of {index.path} could be "
                               f"calibrated: " + "; ".join(skipped[:3]))
    comb = combine_windows(posts)
    fact = WindowsCombined(window_s=window_frames * index.frame_period_s, n_windows=n,
                           n_combined=len(posts), skipped=tuple(skipped),
                           spread_chi2=comb.spread_chi2, spread_dof=comb.spread_dof,
                           spread_factor=comb.spread_factor)
    return _result(first, comb, fact, index.node_names)
