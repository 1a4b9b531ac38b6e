"""The view's geometry (mmsnap_graph.app.view.scene), against independent
formulas."""

from __future__ import annotations

import numpy as np
import pytest

from mmsnap_graph.app.view.scene import (TrackHistory, boresight, covariance_ellipse,
                                         detections_xy, field_of_view, id_color)
from mmsnap_graph.data.recording import Detections
from mmsnap_graph.errors import ValidationError


@pytest.mark.parametrize("cov", [[[0.04, 0.015], [0.015, 0.01]], [[0.5, 0.0], [0.0, 0.02]],
                                 [[0.01, -0.009], [-0.009, 0.01]]])
def test_ellipse_points_lie_on_the_two_sigma_contour(cov):
    c, p = np.array([1.5, -2.0]), np.array(cov)
    e = covariance_ellipse(c, p, n_sigma=2.0, n_points=64)
    d = e - c
    m2 = np.einsum("ki,ij,kj->k", d, np.linalg.inv(p), d)
    np.testing.assert_allclose(m2, 4.0, rtol=1e-10)
    # Its half axes are 2 sqrt of the eigenvalues (the farthest and nearest points).
    w = np.linalg.eigvalsh(p)
    r = np.linalg.norm(d, axis=1)
    assert r.max() == pytest.approx(2 * np.sqrt(w[1]), rel=2e-3)
    assert r.min() == pytest.approx(2 * np.sqrt(w[0]), rel=2e-3)


def test_a_singular_covariance_is_a_flat_ellipse_and_bad_ones_are_refused():
    e = covariance_ellipse([0.0, 0.0], [[1.0, 1.0], [1.0, 1.0]])
    np.testing.assert_allclose(e[:, 0], e[:, 1], atol=1e-12)     # all on the line y = x
    assert np.abs(e).max() == pytest.approx(2 * np.sqrt(2) / np.sqrt(2), rel=1e-2)
    with pytest.raises(ValidationError, match="not positive semi-definite"):
        covariance_ellipse([0, 0], [[1.0, 0.0], [0.0, -1.0]])
    with pytest.raises(ValidationError, match="must be finite"):
        covariance_ellipse([np.nan, 0], np.eye(2))
    with pytest.raises(ValidationError, match=r"\(2, 2\)"):
        covariance_ellipse([0, 0], np.eye(3))


def test_field_of_view_is_an_arc_about_the_boresight():
    pose = np.array([1.0, 2.0, np.deg2rad(30.0)])
    fov = field_of_view(pose, half_angle_rad=np.deg2rad(60.0), range_m=4.0, n_arc=25)
    np.testing.assert_allclose(fov[0], pose[:2])
    np.testing.assert_allclose(fov[-1], pose[:2])
    arc = fov[1:-1] - pose[:2]
    np.testing.assert_allclose(np.linalg.norm(arc, axis=1), 4.0)
    bore = np.array([-np.sin(pose[2]), np.cos(pose[2])])   # docs/CONVENTIONS.md
    angles = np.degrees(np.arccos(np.clip(arc @ bore / 4.0, -1, 1)))
    assert angles.max() == pytest.approx(60.0) and angles[12] == pytest.approx(0.0, abs=1e-6)
    tip = boresight(pose, 0.5)
    np.testing.assert_allclose(tip[1] - tip[0], 0.5 * bore)


def test_detections_in_the_reference_frame():
    """r sin(theta), r cos(theta) in the node's frame (omega = pi sin theta),
    then turned by phi and moved to the node."""
    pose = np.array([3.0, 1.0, np.pi / 2])
    r, theta = np.array([2.0, 3.0]), np.array([0.3, -0.5])
    det = Detections(frame=np.zeros(2, np.int64), range_m=r, omega_rad=np.pi * np.sin(theta),
                     doppler_mps=np.zeros(2))
    local = np.stack([r * np.sin(theta), r * np.cos(theta)], -1)
    want = pose[:2] + local @ np.array([[0.0, 1.0], [-1.0, 0.0]])   # R(90 deg)^T rows
    np.testing.assert_allclose(detections_xy(det, pose), want, atol=1e-12)
    np.testing.assert_allclose(detections_xy(det.measurements, pose), want, atol=1e-12)
    assert detections_xy(np.zeros((0, 3)), pose).shape == (0, 2)


def test_track_history_keeps_the_last_seconds_of_live_ids_only():
    h = TrackHistory(max_age_s=1.0)
    for k in range(30):
        ids = [0, 1] if k < 10 else [0]
        h.update(0.125 * k, ids, [[k, 0.0], [k, 1.0]][:len(ids)])
    lines = h.lines()
    assert set(lines) == {0}                      # id 1 unseen for > 1 s: dropped
    assert lines[0][0, 0] == 21 and len(lines[0]) == 9   # 2.625 s .. 3.625 s
    with pytest.raises(ValidationError, match="max_age_s"):
        TrackHistory(max_age_s=0.0)


def test_id_colours_repeat_after_ten():
    assert id_color(3) == id_color(13) != id_color(4)
