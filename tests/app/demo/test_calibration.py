"""Self-calibration of a demo run (mmsnap_graph.app.demo.calibration)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mmsnap_graph.errors import CalibrationError, ValidationError
from mmsnap_graph.data.recording import Tracks
from mmsnap_graph.calibration import closed_form_calibration
from mmsnap_graph.app import demo


def test_track_alignment_rmse_is_the_closed_form_rmse_at_its_pose():
    rng = np.random.default_rng(5)
    a = rng.uniform(-2, 2, (50, 2)) + [0, 4]
    pose = np.array([0.3, 6.8, 3.0])
    # b's local points: a seen from the pose, plus noise.
    from factors.models import global_to_local

    b = global_to_local(a, pose) + rng.normal(0, 0.05, (50, 2))
    cf = closed_form_calibration(a, b)
    frames = np.arange(50)
    ta = demo.SingleTrack(frame=frames, state=np.c_[a, np.zeros((50, 2))],
                          covariance=np.zeros((50, 4, 4)), track_id=np.zeros(50, int))
    tb = dataclasses.replace(ta, state=np.c_[b, np.zeros((50, 2))])
    rmse, k = demo.track_alignment_rmse(cf.pose, ta, tb)
    assert k == 50
    assert rmse == pytest.approx(cf.rmse_m, rel=1e-9)
    # Any other pose does worse.
    worse, _ = demo.track_alignment_rmse(cf.pose + [0.05, 0, 0.01], ta, tb)
    assert worse > rmse


def test_calibration_without_tracks_raises():
    rec = demo.simulate_run("B", "straight", n_frames=30, seed=0)
    rec = demo.node_chain(rec)
    empty = dataclasses.replace(rec.nodes["S2"], tracks=Tracks.empty())
    with pytest.raises(CalibrationError, match="closed form failed"):
        demo.calibrate_run(rec.with_node(empty), configuration="B", trajectory="straight")


def test_calibration_needs_two_nodes():
    rec = demo.simulate_run("B", "straight", n_frames=30, seed=0)
    one = dataclasses.replace(rec, nodes={"S1": rec.nodes["S1"]})
    with pytest.raises(ValidationError, match="two-node networks"):
        demo.calibrate_run(one)
