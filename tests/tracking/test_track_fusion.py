"""Track-level fusion by covariance intersection (mmsnap_graph.tracking.track_fusion)."""

import gtsam
import numpy as np
import pytest
from scipy.optimize import minimize_scalar

from mmsnap_graph.errors import ValidationError
from mmsnap_graph.data.recording import Tracks
from mmsnap_graph.sim import simulate_recording
from mmsnap_graph.tracking.ekf import EkfConfig, track_centroids
from mmsnap_graph.tracking.track_fusion import covariance_intersection, fuse_tracks, transform_tracks
from mmsnap_graph.sim import SimulationOptions


def _spd(rng, k, n=4, scale=1.0):
    a = rng.normal(size=(k, n, n + 2)) * scale
    return a @ a.transpose(0, 2, 1) + 1e-3 * np.eye(n)


def test_transform_matches_pose2_and_rotates_every_block():
    rng = np.random.default_rng(0)
    pose = np.array([0.3, 6.9, np.pi - 0.1])
    x = rng.normal(size=(5, 4))
    p = _spd(rng, 5)
    xg, pg = transform_tracks(x, p, pose)
    pose2 = gtsam.Pose2(*pose)
    for k in range(5):
        np.testing.assert_allclose(xg[k, :2], pose2.transformFrom(x[k, :2]), atol=1e-12)
        np.testing.assert_allclose(xg[k, 2:], pose2.rotation().rotate(x[k, 2:]), atol=1e-12)
    # The covariance of the transformed samples (Monte Carlo) is T P T^T.
    samples = rng.multivariate_normal(x[0], p[0], size=200_000)
    sg, _ = transform_tracks(samples, np.broadcast_to(p[0], (200_000, 4, 4)), pose)
    np.testing.assert_allclose(np.cov(sg.T), pg[0], atol=0.02 * np.abs(pg[0]).max())
    assert np.allclose(pg, pg.transpose(0, 2, 1))
    # S1 at the origin: unchanged.
    x0, p0 = transform_tracks(x, p, np.zeros(3))
    np.testing.assert_allclose(x0, x, atol=1e-15)
    np.testing.assert_allclose(p0, p, atol=1e-15)


def test_ci_weight_minimizes_the_trace():
    rng = np.random.default_rng(1)
    p1, p2 = _spd(rng, 20), _spd(rng, 20)
    x1, x2 = rng.normal(size=(20, 4)), rng.normal(size=(20, 4))
    x, p, w = covariance_intersection(x1, p1, x2, p2)
    for k in range(20):
        a, b = np.linalg.inv(p1[k]), np.linalg.inv(p2[k])

        def tr(om):
            return np.trace(np.linalg.inv(om * a + (1 - om) * b))

        ref = minimize_scalar(tr, bounds=(0, 1), method="bounded", options={"xatol": 1e-12})
        assert tr(w[k]) <= ref.fun + 1e-9 * ref.fun
        info = w[k] * a + (1 - w[k]) * b
        np.testing.assert_allclose(p[k], np.linalg.inv(info), rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(x[k], np.linalg.solve(info, w[k] * a @ x1[k] + (1 - w[k]) * b @ x2[k]),
                                   rtol=1e-8, atol=1e-10)


def test_ci_picks_the_tighter_of_nested_estimates_and_is_symmetric():
    rng = np.random.default_rng(2)
    p1 = _spd(rng, 3)
    p2 = 4.0 * p1 + _spd(rng, 3)  # p2 contains p1
    x1, x2 = rng.normal(size=(3, 4)), rng.normal(size=(3, 4))
    x, p, w = covariance_intersection(x1, p1, x2, p2)
    np.testing.assert_array_equal(w, 1.0)
    np.testing.assert_allclose(x, x1, atol=1e-12)
    np.testing.assert_allclose(p, p1, rtol=1e-10, atol=1e-12)
    xs, ps, ws = covariance_intersection(x2, p2, x1, p1)
    np.testing.assert_allclose(ws, 1.0 - w)
    np.testing.assert_allclose(xs, x, atol=1e-10)


def test_ci_is_consistent_whatever_the_unknown_correlation():
    """CI never under-estimates: for fully correlated errors P - cov(err) >= 0."""
    p1 = np.diag([0.01, 0.5, 0.04, 0.5])[None]
    p2 = np.diag([0.5, 0.01, 0.5, 0.04])[None]
    _, p, w = covariance_intersection(np.zeros((1, 4)), p1, np.zeros((1, 4)), p2)
    # Errors e2 = L2 L1^-1 e1 (perfectly correlated), fused error = K1 e1 + K2 e2.
    info = w[0] * np.linalg.inv(p1[0]) + (1 - w[0]) * np.linalg.inv(p2[0])
    k1 = np.linalg.solve(info, w[0] * np.linalg.inv(p1[0]))
    k2 = np.linalg.solve(info, (1 - w[0]) * np.linalg.inv(p2[0]))
    m = k1 + k2 @ np.sqrt(p2[0]) @ np.linalg.inv(np.sqrt(p1[0]))
    true_cov = m @ p1[0] @ m.T
    assert np.linalg.eigvalsh(p[0] - true_cov).min() > -1e-12


def test_fused_ekf_tracks_follow_the_target():
    rec = simulate_recording("C", "random",
                             SimulationOptions(physics=None, known_poses=True, centroid_p_miss=0.05),
                             levels=("centroids",), n_frames=200, seed=4)
    config = EkfConfig(frame_period_s=rec.frame_period_s)
    t1 = track_centroids(rec.nodes["S1"].centroids, config)
    t2 = track_centroids(rec.nodes["S2"].centroids, config)
    fused = fuse_tracks(t1, rec.nodes["S1"].pose, t2, rec.nodes["S2"].pose)
    assert len(fused) > 150
    assert np.all((fused.omega >= 0) & (fused.omega <= 1))
    _, truth = rec.truth.target(0)
    err = fused.state - truth[fused.frame]
    assert np.sqrt(np.mean(np.sum(err[:, :2] ** 2, axis=1))) < 0.35
    tr = fused.as_tracks()
    assert len(tr) == len(fused)
    # Fusing with a wrong pose for S2 (3 m off) moves S2's tracks off S1's:
    # the gate rejects the pairs.
    wrong = rec.nodes["S2"].pose + [3.0, 0.0, 0.0]
    assert len(fuse_tracks(t1, rec.nodes["S1"].pose, t2, wrong)) < 0.2 * len(fused)


def _one_track_per_frame(rng, frames, offset):
    k = len(frames)
    state = np.c_[rng.normal(0.0, 0.1, (k, 2)) + [0.0, 4.0], rng.normal(0.0, 0.3, (k, 2))] + offset
    return Tracks(frame=frames, track_id=np.full(k, 7), state=state,
                  covariance=_spd(rng, k, scale=0.1))


def test_one_track_per_frame_fuses_every_common_frame_by_ci():
    """With one track per node and frame (single-target tracks) and no gate,
    every common frame is fused: covariance intersection of the two tracks
    moved into the global frame, in increasing frame order."""
    rng = np.random.default_rng(7)
    t1 = _one_track_per_frame(rng, np.array([5, 1, 2, 3, 9]), 0.0)
    t2 = _one_track_per_frame(rng, np.array([0, 1, 2, 3, 5, 6]), 0.0)
    # S2's tracks land 5 m from S1's: only the ungated fusion pairs them.
    pose_1, pose_2 = np.zeros(3), np.array([5.0, 8.0, np.pi])
    out = fuse_tracks(t1, pose_1, t2, pose_2, gate_probability=None)
    np.testing.assert_array_equal(out.frame, [1, 2, 3, 5])
    np.testing.assert_array_equal(out.track_id_1, 7)
    x1, p1 = transform_tracks(t1.state, t1.covariance, pose_1)
    x2, p2 = transform_tracks(t2.state, t2.covariance, pose_2)
    i1 = [1, 2, 3, 0]
    i2 = [1, 2, 3, 4]
    x, p, w = covariance_intersection(x1[i1], p1[i1], x2[i2], p2[i2])
    np.testing.assert_array_equal(out.state, x)
    np.testing.assert_array_equal(out.covariance, p)
    np.testing.assert_array_equal(out.omega, w)
    # Far apart (S2's tracks are not where S1's are): the default gate drops them all.
    assert len(fuse_tracks(t1, pose_1, t2, pose_2)) == 0


def test_one_track_per_frame_agrees_with_the_assignment_per_frame():
    """The vectorized pairing of single tracks gives what the per-frame gated
    assignment gives (a second S1 track in a frame S2 lacks forces the
    assignment path without changing any pair)."""
    rec = simulate_recording("B", "straight", SimulationOptions(physics=None, known_poses=True),
                             levels=("centroids",), n_frames=80, seed=2)
    config = EkfConfig(frame_period_s=rec.frame_period_s)
    tracks = [track_centroids(rec.nodes[n].centroids, config) for n in ("S1", "S2")]
    single = []
    for t in tracks:  # one row per frame: the first track alive
        _, first = np.unique(t.frame, return_index=True)
        single.append(t.select(first))
    poses = [rec.nodes[n].pose for n in ("S1", "S2")]
    fast = fuse_tracks(single[0], poses[0], single[1], poses[1])
    extra_frame = int(single[0].frame.max()) + 10
    s1 = single[0]
    doubled = Tracks(frame=np.r_[s1.frame, extra_frame, extra_frame],
                     track_id=np.r_[s1.track_id, 90, 91],
                     state=np.r_[s1.state, s1.state[:2]],
                     covariance=np.r_[s1.covariance, s1.covariance[:2]])
    slow = fuse_tracks(doubled, poses[0], single[1], poses[1])
    assert len(fast) > 40
    for field in ("frame", "track_id_1", "track_id_2", "state", "covariance", "omega"):
        np.testing.assert_array_equal(getattr(fast, field), getattr(slow, field))
    # A wrong pose for S2: both paths gate the same pairs out.
    wrong = poses[1] + [0.5, 0.0, 0.0]
    np.testing.assert_array_equal(fuse_tracks(single[0], poses[0], single[1], wrong).frame,
                                  fuse_tracks(doubled, poses[0], single[1], wrong).frame)


def test_no_common_frames_gives_an_empty_result():
    one = Tracks(frame=[0], track_id=[0], state=[[0, 3, 0, 0]], covariance=[np.eye(4)])
    other = Tracks(frame=[1], track_id=[0], state=[[0, 3, 0, 0]], covariance=[np.eye(4)])
    out = fuse_tracks(one, np.zeros(3), other, np.zeros(3))
    assert len(out) == 0 and out.state.shape == (0, 4)


@pytest.mark.parametrize(
    "call, match",
    [
        (lambda: transform_tracks(np.zeros((2, 4)), np.zeros((3, 4, 4)), np.zeros(3)), "disagree"),
        (lambda: transform_tracks(np.zeros((1, 4)), np.eye(4)[None], np.zeros(2)), r"node_pose must have shape \(3,\)"),
        (lambda: covariance_intersection(np.zeros((1, 4)), np.zeros((1, 4, 4)), np.zeros((1, 4)), np.eye(4)[None]),
         "p1 must be positive definite"),
        (lambda: covariance_intersection(np.zeros((1, 4)), np.eye(4)[None], np.zeros((2, 4)), np.eye(4)[None]),
         "disagree"),
        (lambda: fuse_tracks(Tracks.empty(), np.zeros(3), None, np.zeros(3)), "must be Tracks"),
        (lambda: fuse_tracks(Tracks.empty(), np.zeros(3), Tracks.empty(), np.zeros(3), gate_probability=2),
         "gate_probability"),
        (lambda: fuse_tracks(Tracks.empty(), np.zeros(3), Tracks.empty(), np.zeros(3), gate_probability=1.0),
         r"gate_probability must be in \(0, 1\) or None"),
    ],
)
def test_invalid_input_raises(call, match):
    with pytest.raises(ValidationError, match=match):
        call()
