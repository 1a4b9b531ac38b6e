"""The live refinement (calibration/online.py): windows combined as they
close, the refined poses converge to the truth from a wrong start, a moved
radar is noticed and re-calibrated alone, the others untouched."""

from __future__ import annotations

import functools

import numpy as np
import pytest

from mmsnap_graph.calibration.joint.windowed import combine_windows
from mmsnap_graph.calibration.online import OnlineRefinement, PoseUpdate, without_node
from mmsnap_graph.calibration.poses import pose_tangent_error
from mmsnap_graph.data.noise import declared_noise
from mmsnap_graph.errors import ValidationError
from mmsnap_graph.sim.bump import simulate_bumped_recording

NET = {"S1": (0.0, 0.0, 0.0), "S2": (0.0, 7.0, np.pi), "S3": (-3.5, 3.5, -np.pi / 2)}
PERIOD = 0.15
WRONG = np.array([0.05, -0.04, np.deg2rad(1.0)])      # the stored calibration's error


@functools.cache
def _bumped(seed: int, bump=(0.1, 0.0, 0.0), n_frames=800, bump_time_s=60.0):
    return simulate_bumped_recording(NET, "random", physics=None, node="S3", bump=bump,
                                     bump_time_s=bump_time_s, n_frames=n_frames,
                                     frame_period_s=PERIOD, seed=seed)


def _run(rec, refinement) -> list[PoseUpdate]:
    """Every frame's centroids given to ``refinement`` in order."""
    names = rec.node_names
    cents = {n: rec.nodes[n].centroids for n in names}
    frames = max(int(c.frame.max()) for c in cents.values()) + 1
    cuts = {n: np.searchsorted(c.frame, np.arange(frames + 1)) for n, c in cents.items()}
    out = []
    for f in range(frames):
        out += refinement.add(f, {n: cents[n].measurements[cuts[n][f]:cuts[n][f + 1]]
                                  for n in names})
    return out + refinement.finish()


def _wrong_start():
    return {n: np.asarray(p) + (WRONG if n != "S1" else 0.0) for n, p in NET.items()}


def test_the_refined_poses_converge_to_the_truth_from_a_wrong_start():
    rec = _bumped(0, bump=(0.0, 0.0, 0.0), n_frames=600)      # no move
    ref = OnlineRefinement(_wrong_start(), frame_period_s=PERIOD,
                           noise=declared_noise(rec.metadata), window_s=30.0)
    ups = _run(rec, ref)
    windows = [u for u in ups if u.reason == "window"]
    assert len(windows) == 3 and ref.skipped == []
    assert [u.frame for u in windows] == [199, 399, 599]
    assert not [u for u in ups if u.reason in ("change", "recalibrated")]
    start_err = np.linalg.norm(WRONG[:2])
    for u in windows:
        assert u.poses["S1"].tolist() == list(NET["S1"])          # the reference stays
    for n in ("S2", "S3"):
        errs = [np.hypot(*(u.poses[n][:2] - NET[n][:2])) for u in windows]
        assert errs[-1] < 0.3 * start_err, (n, errs)
        e = pose_tangent_error(windows[-1].poses[n], NET[n])
        assert abs(e[2]) < np.deg2rad(0.3), (n, e)
        # the reported covariance covers the error (3 sigma per axis)
        sig = np.sqrt(np.diag(windows[-1].covariances[n]))
        assert np.all(np.abs(e) < 3 * sig), (n, e, sig)
    cal = ref.calibration()
    assert cal.reference == "S1" and set(cal.poses) == set(NET)
    assert np.allclose(cal.poses["S2"], windows[-1].poses["S2"])
    j = windows[-1].to_json()
    assert j["type"] == "calibration" and j["reason"] == "window" and set(j["poses"]) == set(NET)


@pytest.mark.slow
def test_a_moved_radar_is_noticed_and_recalibrated_alone_the_others_untouched():
    rec = _bumped(1)
    truth_after = np.asarray(NET["S3"]) + np.array([0.1, 0.0, 0.0])
    ref = OnlineRefinement(dict(NET), frame_period_s=PERIOD, noise=declared_noise(rec.metadata),
                           window_s=30.0)
    ups = _run(rec, ref)
    changes = [u for u in ups if u.reason == "change"]
    recals = [u for u in ups if u.reason == "recalibrated"]
    assert [u.nodes for u in changes] == [("S3",)] and [u.nodes for u in recals] == [("S3",)]
    bump_s = rec.metadata["bump_time_s"]
    assert bump_s <= changes[0].time_s < bump_s + 15.0
    # the re-calibration moves S3 only
    before = [u for u in ups if u.frame < recals[0].frame][-1]
    for n in ("S1", "S2"):
        assert np.array_equal(recals[0].poses[n], before.poses[n])
    assert np.hypot(*(recals[0].poses["S3"][:2] - truth_after[:2])) < 0.1
    # the windows after it: S3 at its new pose, S2 still at the truth
    last = [u for u in ups if u.reason == "window"][-1]
    assert last.frame > recals[0].frame
    assert np.hypot(*(last.poses["S3"][:2] - truth_after[:2])) < 0.03
    for n, truth in (("S3", truth_after), ("S2", NET["S2"])):
        e = pose_tangent_error(last.poses[n], truth)
        assert np.all(np.abs(e) < 3 * np.sqrt(np.diag(last.covariances[n]))), (n, e)


def test_a_node_marginalised_out_of_a_window_keeps_the_others_block():
    rec = _bumped(0, bump=(0.0, 0.0, 0.0), n_frames=200, bump_time_s=10.0)
    ref = OnlineRefinement(dict(NET), frame_period_s=PERIOD, noise=declared_noise(rec.metadata),
                           window_s=30.0, monitor=False)
    _run(rec, ref)
    (post,) = ref._posteriors
    less = without_node(post, "S3")
    assert all(lab[1] != "S3" for lab in less.labels if len(lab) > 1)
    keep = [post.labels.index(lab) for lab in less.labels]
    np.testing.assert_array_equal(less.random, post.random[np.ix_(keep, keep)])
    assert ("pose", "S3", 0) not in combine_windows([less]).labels
    # a window's marginal: S2 as the whole window gives it (estimate, covariance)
    alone, whole = combine_windows([less]), combine_windows([post])
    np.testing.assert_allclose(alone.poses()["S2"], whole.poses()["S2"], atol=1e-12)
    np.testing.assert_allclose(alone.block("S2"), whole.block("S2"), rtol=1e-9, atol=1e-15)


def test_a_window_far_from_the_current_poses_is_left_out_not_combined():
    rec = _bumped(0, bump=(0.0, 0.0, 0.0), n_frames=400, bump_time_s=10.0)
    start = dict(NET)
    start["S2"] = np.asarray(NET["S2"]) + [1.0, 0.0, 0.0]     # 10 sigmas: no refinement
    ref = OnlineRefinement(start, frame_period_s=PERIOD, noise=declared_noise(rec.metadata),
                           window_s=30.0, monitor=False)
    ups = _run(rec, ref)
    assert ups == [] and len(ref.skipped) == 2
    assert all("S2's pose is 0.9" in why for why in ref.skipped), ref.skipped
    assert np.array_equal(ref.poses["S2"], start["S2"])


def test_bad_options_name_the_flag():
    with pytest.raises(ValidationError, match="--refine-window-s"):
        OnlineRefinement(dict(NET), frame_period_s=PERIOD, window_s=1.0)
    with pytest.raises(ValidationError, match="--refine-window-s"):
        OnlineRefinement(dict(NET), frame_period_s=PERIOD, window_s=-3.0)
    with pytest.raises(ValidationError, match="at least 2 nodes"):
        OnlineRefinement({"S1": (0, 0, 0)}, frame_period_s=PERIOD)
