"""Mounting and point-cloud checks (mmsnap_graph.io.ti.point_cloud)."""

from __future__ import annotations

import numpy as np
import pytest

from mmsnap_graph.errors import ValidationError
from mmsnap_graph.io.ti.point_cloud import (Mounting, PointCloud3D, accumulate_frames,
                                         check_frame_period)


def test_a_height_in_centimetres_is_named():
    assert Mounting(height_m=11.5).height_m == 11.5
    with pytest.raises(ValidationError, match=r"height_m=80.0 lies beyond \+-12 m: the height "
                                              r"is in metres \(centimetres\? 80 cm is 0.8 m\)"):
        Mounting(height_m=80.0, tilt_rad=0.1)


def _cloud(frames, stamps):
    n = len(frames)
    return PointCloud3D(frame=frames, x_m=np.zeros(n), y_m=np.ones(n), z_m=np.zeros(n),
                        doppler_mps=np.zeros(n), time_s=stamps)


def test_frame_period_check():
    frames = np.repeat(np.arange(50), 3)
    good = _cloud(frames, 100.0 + 0.05 * frames)
    assert check_frame_period(good, 0.05) is None
    assert "advance 0.05 s per frame" in check_frame_period(good, 0.1)
    coarse = _cloud(frames, np.floor(100.0 + 0.05 * frames))
    assert "coarser than a frame" in check_frame_period(coarse, 0.05)


def test_accumulated_stamps_move_with_their_frame():
    frames = np.arange(5)
    cloud = accumulate_frames(_cloud(frames, 10.0 + 0.1 * frames), 2, frame_period_s=0.1)
    np.testing.assert_allclose(cloud.time_s - 10.0, 0.1 * cloud.frame)
    with pytest.raises(ValidationError, match="would make"):
        accumulate_frames(_cloud(frames, 10.0 + 0.1 * frames), 10 ** 8)
