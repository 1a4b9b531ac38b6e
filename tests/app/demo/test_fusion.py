"""The demo's fusion of a run (mmsnap_graph.app.demo.fusion): the track-level benchmark."""

from __future__ import annotations

import numpy as np
import pytest

from mmsnap_graph.errors import ValidationError
from mmsnap_graph.tracking.track_fusion import covariance_intersection
from mmsnap_graph.app import demo
from factors.models import local_to_global


def test_track_level_fusion_is_ci_on_common_frames():
    """The demo's benchmark: per common frame, covariance intersection of the
    two single-target tracks moved into the global frame (no gate)."""
    rng = np.random.default_rng(11)

    def track(frames):
        k = len(frames)
        a = rng.normal(size=(k, 4, 6)) * 0.2
        return demo.SingleTrack(frame=np.asarray(frames), state=rng.normal(size=(k, 4)) + [0, 4, 0, 0],
                                covariance=a @ a.transpose(0, 2, 1) + 1e-3 * np.eye(4),
                                track_id=np.arange(k))

    ta, tb = track([0, 1, 2, 4, 7]), track([1, 2, 3, 4, 8])
    poses = (np.zeros(3), np.array([3.0, 9.0, np.pi + 0.3]))
    frames, states = demo.track_level_fusion((ta, tb), poses)
    np.testing.assert_array_equal(frames, [1, 2, 4])
    xa, pa = demo.global_track(ta, poses[0])
    xb, pb = demo.global_track(tb, poses[1])
    ia, ib = [1, 2, 3], [0, 1, 3]
    x, _, _ = covariance_intersection(xa[ia], pa[ia], xb[ib], pb[ib])
    np.testing.assert_array_equal(states, x)
    empty, _ = demo.track_level_fusion((ta, track([20])), poses)
    assert empty.size == 0
    with pytest.raises(ValidationError, match="two nodes"):
        demo.track_level_fusion((ta,), poses[:1])


def test_global_track_moves_position_and_rotates_velocity():
    pose = np.array([0.0, 7.0, np.pi])
    st = demo.SingleTrack(frame=np.array([0]), state=np.array([[1.0, 2.0, 0.5, -0.2]]),
                          covariance=np.diag([0.1, 0.2, 0.3, 0.4])[None], track_id=np.array([0]))
    x, p = demo.global_track(st, pose)
    np.testing.assert_allclose(x[0, :2], local_to_global(np.array([1.0, 2.0]), pose))
    np.testing.assert_allclose(x[0, 2:], [-0.5, 0.2], atol=1e-12)
    np.testing.assert_allclose(np.diag(p[0]), [0.1, 0.2, 0.3, 0.4], atol=1e-12)
