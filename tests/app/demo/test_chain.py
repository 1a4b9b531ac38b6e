"""Each node's chain in the demo (mmsnap_graph.app.demo.chain): one walker's track and
centroids."""

from __future__ import annotations

import numpy as np

from mmsnap_graph.data.recording import Detections, Tracks
from mmsnap_graph.app import demo


def _tracks(rows):
    frame, tid, state, cov = zip(*rows)
    return Tracks(frame=np.array(frame), track_id=np.array(tid), state=np.array(state),
                  covariance=np.array(cov))


def test_single_target_track_keeps_the_updated_track_at_a_handover():
    small, big = np.eye(4) * 0.01, np.eye(4) * 1.0
    tr = _tracks([(0, 1, [0, 0, 0, 0], small), (1, 1, [1, 0, 0, 0], big),
                  (1, 2, [2, 0, 0, 0], small), (2, 2, [3, 0, 0, 0], small)])
    st = demo.single_target_track(tr)
    np.testing.assert_array_equal(st.frame, [0, 1, 2])
    np.testing.assert_array_equal(st.track_id, [1, 2, 2])
    np.testing.assert_array_equal(st.state[:, 0], [0, 2, 3])
    assert len(demo.single_target_track(Tracks.empty())) == 0


def test_centroids_near_track_picks_one_centroid_per_frame_on_the_track():
    # Frame 0: the target at 3 m broadside and a false alarm at 8 m; frame 1:
    # only a false alarm, but the track has no row there.
    det = Detections(frame=[0, 0, 1], range_m=[3.0, 8.0, 5.0], omega_rad=[0.0, 0.5, 0.0],
                     doppler_mps=[0.1, -1.0, 0.0])
    track = demo.SingleTrack(frame=np.array([0]), state=np.array([[0.0, 3.05, 0, 0]]),
                             covariance=np.zeros((1, 4, 4)), track_id=np.array([0]))
    out = demo.centroids_near_track(det, track)
    np.testing.assert_array_equal(out.frame, [0])
    assert out.range_m[0] == 3.0
