"""The windowed joint calibration: the policy of when, the combination of
the windows' pose posteriors, and its covariance against the truth."""

from __future__ import annotations

import dataclasses
import functools
import json
from pathlib import Path

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

    def second_singular(cal, joint):
        post = real(cal, joint)
        calls.append(1)
        return dataclasses.replace(post, random=np.zeros_like(post.random)) \
            if len(calls) == 2 else post

    monkeypatch.setattr(w, "window_posterior", second_singular)
    win = w.calibrate_windowed(open_detection_windows(clean_file), 150)
    fact = win.facts[0]
    assert (fact.n_windows, fact.n_combined) == (2, 1)
    assert fact.skipped == ("frames 150-299: its pose covariance is not positive definite",)


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
# NEES 2.27, band (1.55, 4.92); S2's position RMS windowed 0.142 m, batch
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
