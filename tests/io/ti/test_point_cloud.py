"""Mounting and point-cloud checks (mmsnap_graph.io.ti.point_cloud)."""

from __future__ import annotations

import numpy as np
import pytest

from mmsnap_graph.errors import ValidationError
from mmsnap_graph.io.ti.point_cloud import (Mounting, PointCloud3D, accumulate_frames,
                                            check_frame_period, stamp_unit_factor)


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


def test_stamps_in_milliseconds_without_frame_numbers_are_a_unit_error():
    """Frames numbered from stamps in ms read as s lie 1000 frames apart
    (a real table gave frames 0-643000 and processed to no centroid)."""
    frames = np.repeat(np.arange(50), 3)
    stamps_ms = 50.0 * frames                        # 20 fps, in milliseconds
    as_seconds = _cloud(np.round(stamps_ms / 0.05).astype(int), stamps_ms)
    assert stamp_unit_factor(as_seconds, 0.05) == 1e3
    problem = check_frame_period(as_seconds, 0.05)
    assert "a median 1000 frames" in problem and "a factor of 1000" in problem
    right = _cloud(frames, stamps_ms * 1e-3)
    assert stamp_unit_factor(right, 0.05) is None and check_frame_period(right, 0.05) is None
    # A frame column: the stamps advance 1000 periods per frame, or a thousandth.
    assert stamp_unit_factor(_cloud(frames, stamps_ms), 0.05) == 1e3
    assert stamp_unit_factor(_cloud(frames, stamps_ms * 1e-6), 0.05) == 1e-3
    # Stamps in s read as ms: one stamp per frame, all merged into frame 0.
    merged = _cloud(np.zeros(frames.size, int), stamps_ms * 1e-6)
    assert stamp_unit_factor(merged, 0.05) == 1e-3
    assert "a factor of 0.001" in check_frame_period(merged, 0.05)
    # A sparse but real log (a person every other frame) is no unit error.
    assert stamp_unit_factor(_cloud(2 * frames, 0.1 * frames), 0.05) is None
