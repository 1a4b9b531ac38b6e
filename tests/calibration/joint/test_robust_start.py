"""Robust starting values of the joint calibration
(mmsnap_graph.calibration.joint.robust_start): the trimmed closed form."""

from __future__ import annotations

import numpy as np
from numpy.testing import assert_allclose

from factors.models import global_to_local
from mmsnap_graph.calibration import closed_form_calibration, pose_tangent_error
from mmsnap_graph.sim.scenes import PAPER_CONFIGURATIONS


def test_robust_start_survives_forty_percent_gross_outliers():
    """trimmed_closed_form (least median of squares, then trimming): 40% of
    the frames replaced by points anywhere in a 20 m box; the plain closed
    form is dragged metres away, the robust one stays at the noise level."""
    from mmsnap_graph.calibration import trimmed_closed_form

    rng = np.random.default_rng(14)
    pose_b = PAPER_CONFIGURATIONS["A"]["S2"]
    pts = rng.uniform([0, 3], [4, 7], size=(200, 2))
    za = pts + rng.normal(size=pts.shape) * 0.05
    zb = global_to_local(pts, pose_b) + rng.normal(size=pts.shape) * 0.05
    bad = rng.random(200) < 0.4
    zb[bad] = rng.uniform(-10, 10, size=(int(bad.sum()), 2))
    plain = closed_form_calibration(za, zb)
    robust, keep = trimmed_closed_form(za, zb)
    assert np.hypot(*pose_tangent_error(plain.pose, pose_b)[:2]) > 1.0
    err = pose_tangent_error(robust.pose, pose_b)
    assert np.hypot(err[0], err[1]) < 0.05 and abs(err[2]) < np.radians(1)
    assert np.mean(keep[bad]) < 0.05 and np.mean(keep[~bad]) > 0.9
    # deterministic
    again, _ = trimmed_closed_form(za, zb)
    assert_allclose(again.pose, robust.pose)
