"""The windowed joint calibration: the policy of when, the combination of
the windows' pose posteriors, and its covariance against the truth."""

from __future__ import annotations

import dataclasses
import functools
import json
from pathlib import Path

import gtsam
import numpy as np
import pytest

from mmsnap_graph.app.cli import main
from mmsnap_graph.calibration import calibrate_recording
from mmsnap_graph.calibration.joint.windowed import (
    WINDOW_S,
    WINDOWED_ABOVE_S,
    WindowPosterior,
    calibrate_windowed,
    combine_windows,
    window_frames_for,
)
from mmsnap_graph.calibration.poses import pose_tangent_error
from mmsnap_graph.data.calibration_facts import WindowsCombined
from mmsnap_graph.errors import ValidationError
from mmsnap_graph.io.chunks import open_detection_windows
from mmsnap_graph.io.hdf5 import read_recording, write_recording


def test_the_policy_windows_only_long_recordings_or_when_asked():
    period = 0.15
    short = int(WINDOWED_ABOVE_S / period)
    assert window_frames_for(short, period) is None
    assert window_frames_for(short + 1, period) == round(WINDOW_S / period)
    assert window_frames_for(3000, period, 60.0) == 400
    assert window_frames_for(300, period, 60.0) is None       # fits in one window
    assert window_frames_for(10**6, period, float("inf")) is None  # one solve, asked
    for bad in (0.0, -5.0, float("nan"), 1.0):                # 1 s: 7 frames, too few
        with pytest.raises(ValidationError, match="--window-s"):
            window_frames_for(3000, period, bad)


def _window(y, random, depth=None, cols=(), widening=None):
    labels = (("pose", "S2", 0), ("pose", "S2", 1), ("pose", "S2", 2))
    return WindowPosterior(labels=labels, poses={"S1": np.zeros(3), "S2": np.asarray(y, float)},
                           offsets={}, range_offset_m=float("nan"), random=np.asarray(random),
                           model=np.asarray(random), depth=(np.zeros((3, 0)) if depth is None
                                                            else np.asarray(depth)),
                           depth_columns=cols, rms=0.1 if depth is not None else 0.0,
                           widening=widening or {"S2": np.zeros((3, 3))})


def test_the_random_part_averages_down_the_reflection_depth_does_not():
    """Four windows at one pose: the noise's covariance falls 4x, the
    considered depth (the same person in every window) stays whole; taken
    as independent it would fall 4x too."""
    pose = np.array([3.0, 1.0, 0.5])
    r = np.diag([0.02, 0.02, 0.001]) ** 2
    m = np.array([[0.8], [0.1], [0.01]])
    one = combine_windows([_window(pose, r, m, (("common",),))])
    four = combine_windows([_window(pose, r, m, (("common",),)) for _ in range(4)])
    depth = 0.1**2 * m @ m.T
    assert np.allclose(one.covariance, r + depth)
    assert np.allclose(four.covariance, r / 4 + depth)
    assert np.allclose(four.poses()["S2"], pose) and four.spread_factor == 1.0


def test_windows_that_disagree_beyond_their_covariances_widen_it():
    r = np.diag([0.01, 0.01, 0.001]) ** 2
    rng = np.random.default_rng(0)
    agree = [_window(np.array([3.0, 1.0, 0.5]) + rng.multivariate_normal(np.zeros(3), r), r)
             for _ in range(6)]
    apart = [_window(np.array([3.0 + 0.05 * (-1) ** i, 1.0, 0.5]), r) for i in range(6)]
    ok, wide = combine_windows(agree), combine_windows(apart)
    assert ok.spread_factor == 1.0 and ok.spread_dof == 15
    # 0.05 m apart with 0.01 m sigmas: chi2 = 6 * 25 = 150 over 15 dof
    assert wide.spread_chi2 == pytest.approx(150.0) and wide.spread_factor == pytest.approx(10.0)
    assert np.allclose(wide.covariance, 10.0 * r / 6)


def test_a_lag_cover_is_a_shift_of_every_window_and_does_not_average_down():
    r = np.diag([0.01, 0.01, 0.001]) ** 2
    d = np.diag([0.05, 0.0, 0.0]) ** 2
    four = combine_windows([_window([3.0, 1.0, 0.5], r, widening={"S2": d}) for _ in range(4)])
    assert np.allclose(four.covariance, r / 4 + d)


def test_windows_with_different_parameters_combine_on_their_union():
    """A clock offset estimated in one window only (kept where the data
    support it): the poses combine over both, the offset is the one
    window's, and the lag cover of the other lands on the poses."""
    r = np.diag([0.01, 0.01, 0.001]) ** 2
    timed = WindowPosterior(
        labels=(("pose", "S2", 0), ("pose", "S2", 1), ("pose", "S2", 2), ("offset", "S2")),
        poses={"S1": np.zeros(3), "S2": np.array([3.0, 1.0, 0.5])}, offsets={"S2": 0.01},
        range_offset_m=float("nan"), random=np.diag([*np.diag(r), 1e-6]),
        model=np.diag([*np.diag(r), 1e-6]), depth=np.ones((4, 1)) * 0.1,
        depth_columns=(("common",),), rms=0.1, widening={"S2": np.zeros((3, 3))})
    d = np.diag([0.05, 0.0, 0.0]) ** 2
    plain = _window([3.0, 1.0, 0.5], r, np.ones((3, 1)) * 0.1, (("common",),),
                    widening={"S2": d})
    both = combine_windows([timed, plain])
    assert both.labels[-1] == ("offset", "S2") and both.estimate[-1] == pytest.approx(0.01)
    assert both.covariance[3, 3] == pytest.approx(1e-6 + 0.1**2 * 0.1**2)
    assert both.covariance[0, 0] == pytest.approx(r[0, 0] / 2 + 0.1**2 * 0.1**2
                                                  + (0.05 / 2) ** 2)


def _window_m(y, model, random, depth=None, cols=(), labels=None, range_prior=None,
              range_m=float("nan")):
    """A window whose graph marginal ``model`` and long-run ``random`` differ."""
    labels = labels or (("pose", "S2", 0), ("pose", "S2", 1), ("pose", "S2", 2))
    k = len(labels)
    return WindowPosterior(labels=labels, poses={"S1": np.zeros(3), "S2": np.asarray(y, float)},
                           offsets={}, range_offset_m=range_m, random=np.asarray(random),
                           model=np.asarray(model), depth=(np.zeros((k, 0)) if depth is None
                                                           else np.asarray(depth)),
                           depth_columns=cols, rms=0.1 if depth is not None else 0.0,
                           widening={"S2": np.zeros((3, 3))}, range_prior=range_prior)


def test_the_windows_combine_as_the_batch_solve_weighs_them():
    """The estimate weighs each window by its graph's information (what
    the batch solve's normal equations do), not by its long-run covariance:
    a window widened x16 in x and heading (errors correlated in time) keeps
    its share; the covariance is the long-run covariances carried through
    those shares (the sandwich). Weighted by the long-run covariances, the
    estimate leaned on the first window (the shared fall-detection
    recording: 1.7x the batch's distance from the tape)."""
    s = np.array([[1.0, 0.5, 0.9], [0.5, 1.0, 0.5], [0.9, 0.5, 1.0]])
    m1 = np.diag([0.012, 0.006, 0.008]) @ s @ np.diag([0.012, 0.006, 0.008])
    m2 = np.diag([0.016, 0.006, 0.013]) @ s @ np.diag([0.016, 0.006, 0.013])
    r1 = 1.5 * m1
    r2 = np.diag([4.0, 1.0, 4.0]) @ m2 @ np.diag([4.0, 1.0, 4.0])
    y1, y2 = np.array([3.0, 1.0, 0.5]), np.array([3.0, 1.0, 0.5]) + np.array([-0.005, 0.002, -0.004])
    both = combine_windows([_window_m(y1, m1, r1), _window_m(y2, m2, r2)])
    h1, h2 = np.linalg.inv(m1), np.linalg.inv(m2)
    cov = np.linalg.inv(h1 + h2)
    step = np.array(gtsam.Pose2.Logmap(gtsam.Pose2(*y1).between(gtsam.Pose2(*y2))))
    want = gtsam.Pose2(*y1).compose(gtsam.Pose2.Expmap(cov @ h2 @ step))
    assert np.allclose(both.poses()["S2"], [want.x(), want.y(), want.theta()], atol=1e-12)
    a1, a2 = cov @ h1, cov @ h2
    assert both.spread_factor == 1.0
    assert np.allclose(both.covariance, a1 @ r1 @ a1.T + a2 @ r2 @ a2.T)
    assert np.allclose(both.model, cov)


def test_the_spread_counts_the_shared_depth_as_shared_not_as_disagreement():
    """Two windows of different geometry see the same reflection depth
    differently (their columns ``M_i`` differ): their estimates differ by
    ``(M_1 - M_2) d`` and the depth's term of the combined covariance holds
    it already; the windows do not disagree, the covariance is not widened
    (counted as disagreement it was widened x5.6 on the fall-detection
    recording, on top of the depth's term)."""
    r = np.diag([0.01, 0.01, 0.002]) ** 2
    m1, m2 = np.array([[0.9], [0.1], [0.05]]), np.array([[-0.2], [0.8], [-0.05]])
    d = 0.15   # 1.5 of its rms 0.1
    truth = gtsam.Pose2(3.0, 1.0, 0.5)

    def moved(m):   # the columns are body-tangent steps
        p = truth.compose(gtsam.Pose2.Expmap(m.ravel() * d))
        return [p.x(), p.y(), p.theta()]

    w1 = _window_m(moved(m1), r, r, m1, (("common",),))
    w2 = _window_m(moved(m2), r, r, m2, (("common",),))
    both = combine_windows([w1, w2])
    # chi2: the depth's own 1.5^2 (a depth of 1.5 rms), not the windows' 0.01 m sigmas
    assert both.spread_factor == 1.0 and both.spread_chi2 == pytest.approx(2.25, abs=0.1)
    m = 0.5 * (m1 + m2)
    assert np.allclose(both.covariance, r / 2 + 0.1**2 * m @ m.T)
    # The same difference without a depth to explain it: widened.
    apart = combine_windows([_window_m(w1.poses["S2"], r, r), _window_m(w2.poses["S2"], r, r)])
    assert apart.spread_factor > 10.0


def test_a_prior_every_window_holds_is_counted_once():
    """The range offset estimated with its prior in every window's graph:
    the combination holds the prior once, the data of every window (the
    batch's information), not the prior once per window."""
    labels = (("pose", "S2", 0), ("pose", "S2", 1), ("pose", "S2", 2), ("range",))
    prior = (0.10, 0.05)
    data_var = 0.02**2
    hp, hd = prior[1] ** -2, 1.0 / data_var
    zs = (0.04, 0.07)   # each window's data alone
    wins = []
    for z in zs:
        post = 1.0 / (hd + hp)
        est = post * (hd * z + hp * prior[0])
        model = np.diag([1e-4, 1e-4, 1e-5, post])
        wins.append(_window_m([3.0, 1.0, 0.5], model, model, labels=labels,
                              range_prior=prior, range_m=est))
    both = combine_windows(wins)
    var = 1.0 / (2 * hd + hp)
    assert both.model[3, 3] == pytest.approx(var)
    assert both.covariance[3, 3] == pytest.approx(var)
    assert both.estimate[3] == pytest.approx(var * (hd * sum(zs) + hp * prior[0]))


@pytest.fixture(scope="module")
def clean_file(tmp_path_factory, three_node_recording):
    rec = three_node_recording(3)
    long = dataclasses.replace(rec)  # 300 frames, 45 s
    path = tmp_path_factory.mktemp("windowed") / "clean.h5"
    write_recording(path, long)
    return path


def test_windows_of_a_clean_recording_give_the_batch_poses(clean_file):
    """Two windows of 150 frames against the batch solve of the 300: the
    poses agree within their sigmas, the covariance is about the batch's."""
    batch = calibrate_recording(read_recording(clean_file))
    said = []
    win = calibrate_windowed(open_detection_windows(clean_file), 150,
                             on_window=lambda *a: said.append(a))
    fact = win.facts[0]
    assert isinstance(fact, WindowsCombined) and (fact.n_windows, fact.n_combined) == (2, 2)
    assert [(a, b) for a, b, _, _ in said] == [(0, 150), (150, 300)]
    assert win.success and win.method == "joint"
    for n in batch.poses:
        if n == batch.reference:
            continue
        d = pose_tangent_error(win.poses[n], batch.poses[n])
        assert d @ np.linalg.solve(batch.covariances[n], d) < 9.0, (n, d)
        ratio = np.diag(win.covariances[n]) / np.diag(batch.covariances[n])
        assert np.all((ratio > 0.5) & (ratio < 2.0)), (n, ratio)
    assert win.joint_covariance.shape == (6, 6) and win.joint_order == ("S2", "S3")


def test_a_short_last_window_joins_the_one_before(clean_file):
    """300 frames by windows of 140: 140 + 160, not 140 + 140 + 20."""
    said = []
    win = calibrate_windowed(open_detection_windows(clean_file), 140,
                             on_window=lambda *a: said.append(a))
    assert [(a, b) for a, b, _, _ in said] == [(0, 140), (140, 300)]
    assert win.facts[0].n_windows == 2


def test_a_window_without_a_usable_covariance_is_left_out_and_named(clean_file, monkeypatch):
    """A window whose pose covariance is singular (a direction the window
    cannot see) would make the combination raise: it is left out."""
    import mmsnap_graph.calibration.joint.windowed as w

    real = w.window_posterior
    calls = []

    def second_singular(cal, joint, **kw):
        post = real(cal, joint, **kw)
        calls.append(1)
        return dataclasses.replace(post, random=np.zeros_like(post.random)) \
            if len(calls) == 2 else post

    monkeypatch.setattr(w, "window_posterior", second_singular)
    win = w.calibrate_windowed(open_detection_windows(clean_file), 150)
    fact = win.facts[0]
    assert (fact.n_windows, fact.n_combined) == (2, 1)
    assert fact.skipped == ("frames 150-299: its pose covariance is not positive definite",)


def test_a_window_that_cannot_be_calibrated_alone_joins_the_next(clean_file, monkeypatch):
    """A window whose data cannot give a pose alone (here: a singular
    covariance) is not lost: its frames are calibrated with the next
    window's (the fall-detection recording in windows of 21 s: a window
    with no matched track joined to the next, S2 0.060 m off the tape
    against 0.096 m with it left out)."""
    import mmsnap_graph.calibration.joint.windowed as w

    real = w.window_posterior
    calls = []

    def first_singular(cal, joint, **kw):
        post = real(cal, joint, **kw)
        calls.append(1)
        return dataclasses.replace(post, random=np.zeros_like(post.random)) \
            if len(calls) == 1 else post

    monkeypatch.setattr(w, "window_posterior", first_singular)
    said = []
    win = w.calibrate_windowed(open_detection_windows(clean_file), 150,
                               on_window=lambda *a: said.append(a))
    fact = win.facts[0]
    assert (fact.n_windows, fact.n_combined, fact.skipped) == (2, 1, ())
    assert [(a, b, c is None) for a, b, c, _ in said] == [(0, 150, True), (0, 300, False)]
    assert said[0][3] == ("its pose covariance is not positive definite (its frames join "
                          "the next window's)")


def test_pose_graph_only_is_refused(clean_file):
    with pytest.raises(ValidationError, match="pose_graph"):
        calibrate_windowed(open_detection_windows(clean_file), 150, method="pose_graph")


# --- the covariance against the truth: the simulator's real model ------------

_FRAMES, _WINDOW = 1200, 400


@functools.lru_cache(maxsize=None)
def _real_model_s2(seed: int, tmp: str) -> tuple:
    """S2's pose errors (body tangent) and reported covariances, windowed
    (3 windows of 60 s) and batch, on one simulated real-model recording
    (network B, people, clutter) after ``mmsnap process``."""
    path = Path(tmp) / f"w{seed}.h5"
    assert main(["simulate", "-c", "B", "-t", "random", "-n", str(_FRAMES), "--seed", str(seed),
                 "-o", str(path)]) == 0
    assert main(["process", str(path)]) == 0
    rec = read_recording(path, load_cubes=False)
    true = rec.truth.node_poses["S2"]
    win = calibrate_windowed(open_detection_windows(path), _WINDOW)
    batch = calibrate_recording(rec)
    return (pose_tangent_error(win.poses["S2"], true), np.asarray(win.covariances["S2"]),
            pose_tangent_error(batch.poses["S2"], true), win.facts[0].n_combined)


# Measured (seeds 0-7, 1200 frames, 3 windows of 400 each combined;
# docs/validation/calibration.md, "Long recordings"): mean pose
# NEES 2.10, band (1.55, 4.92); S2's position RMS windowed 0.140 m, batch
# 0.148 m. The errors are mostly the reflection depth (x_b -0.04..-0.20 m,
# the same in every window): combined as independent, the depth's term
# would shrink 3x (test_the_random_part_averages_down_the_reflection_depth_
# does_not). About 15 s of CPU per seed (16.7 min wall at load 13).
@pytest.mark.slow
def test_windowed_pose_nees_in_band_and_error_within_1_2x_of_batch(tmp_path_factory):
    from mmsnap_graph.evaluation.metrics import nees_check

    tmp = str(tmp_path_factory.mktemp("windowed_real"))
    runs = [_real_model_s2(s, tmp) for s in range(8)]
    errors = np.array([r[0] for r in runs])
    check = nees_check(errors, np.array([r[1] for r in runs]))
    win_rms = np.sqrt(np.mean(np.sum(errors[:, :2] ** 2, axis=1)))
    batch_rms = np.sqrt(np.mean(np.sum(np.array([r[2] for r in runs])[:, :2] ** 2, axis=1)))
    print(f"windowed S2 errors {np.round(errors, 3).tolist()}; NEES {check.mean:.2f} band "
          f"{check.interval}; position RMS windowed {win_rms:.3f} m, batch {batch_rms:.3f} m; "
          f"windows combined {[r[3] for r in runs]}")
    assert check.passed, check
    assert win_rms <= 1.2 * batch_rms


# --- the real recordings (data/real/darksz): against the batch solve ----------

_REAL = {"multiple_tracking": (1.1, 320), "fall_detection": (2.45, 840)}  # S2 height, window
_TAPE_S2 = np.array([1.70, 1.65, np.pi / 2])


# Measured (docs/validation/calibration.md, "Long recordings"): S2 off the
# tape, batch / windowed: multiple tracking (2 windows of 16 s) 0.046 m,
# -3.76 deg / 0.040 m, -3.62 deg; fall detection (2 windows of 42 s)
# 0.059 m, -0.16 deg / 0.054 m, -0.32 deg (weighted by the long-run
# covariances and the depth counted as spread: 0.099 m, +1.93 deg).
@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(_REAL))
def test_windows_of_a_real_recording_give_the_batch_pose(name, tmp_path):
    from _shared import DATA

    height, frames = _REAL[name]
    src, path = DATA / "real" / "darksz", tmp_path / f"{name}.h5"
    assert main(["import", "table", "--node", f"S1={src / (name + '_S1.csv')}",
                 "--node", f"S2={src / (name + '_S2.csv')}", "--frame-period", "0.05",
                 "--mount", "S1=0.8,0", "--mount", f"S2={height},0", "--room-pose", "S1=0,0,0",
                 "--room-pose", "S2=1.7,1.65,90", "--height-band", "0.2,2.0",
                 "-o", str(path)]) == 0
    assert main(["process", str(path)]) == 0
    batch = calibrate_recording(read_recording(path, load_cubes=False))
    win = calibrate_windowed(open_detection_windows(path), frames)
    fact = win.facts[0]
    assert (fact.n_windows, fact.n_combined) == (2, 2)
    b, w = np.asarray(batch.poses["S2"]), np.asarray(win.poses["S2"])
    b_cov, w_cov = np.asarray(batch.covariances["S2"]), np.asarray(win.covariances["S2"])
    b_off, w_off = (float(np.hypot(*(p[:2] - _TAPE_S2[:2]))) for p in (b, w))
    print(f"{name}: S2 off the tape, batch {b_off:.3f} m {np.degrees(b[2] - _TAPE_S2[2]):+.2f} "
          f"deg, windowed {w_off:.3f} m {np.degrees(w[2] - _TAPE_S2[2]):+.2f} deg; sigmas "
          f"batch {np.sqrt(np.diag(b_cov)).round(4)}, windowed {np.sqrt(np.diag(w_cov)).round(4)};"
          f" spread chi2 {fact.spread_chi2:.2f} over {fact.spread_dof}")
    assert w_off <= 1.2 * b_off
    assert abs(w[2] - b[2]) <= 0.25 * np.sqrt(b_cov[2, 2])
    ratio = np.sqrt(np.diag(w_cov) / np.diag(b_cov))
    assert np.all((ratio > 0.8) & (ratio < 1.25)), ratio
    assert fact.spread_factor == 1.0
