"""Multi-target refinement (mmsnap_graph.calibration.joint.multi_refine): rounds
that alternate the association of centroids to targets and the joint solve."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mmsnap_graph.app.pipeline import process_recording
from mmsnap_graph.calibration import calibrate_recording
from mmsnap_graph.calibration.joint.multi_refine import refine_multi
from mmsnap_graph.errors import ValidationError


def test_refine_multi_checks_its_rounds(point_cloud_recording_3):
    proc = process_recording(point_cloud_recording_3)[0]
    pg = calibrate_recording(proc, method="pose_graph")
    with pytest.raises(ValidationError, match="n_rounds"):
        refine_multi(proc, pg, n_rounds=0)


@pytest.mark.slow
def test_more_rounds_do_not_move_a_converged_calibration(point_cloud_recording_3):
    """Rounds stop when the poses stop moving; one round is the old path."""
    meta = {k: v for k, v in point_cloud_recording_3.metadata.items()
            if not k.startswith("centroid_")}
    proc = dataclasses.replace(process_recording(point_cloud_recording_3)[0], metadata=meta)
    pg = calibrate_recording(proc, method="pose_graph")
    one = refine_multi(proc, pg, n_rounds=1)
    three = refine_multi(proc, pg, n_rounds=3)
    assert one.joint.success and three.joint.success
    for n in ("S2", "S3"):
        assert np.hypot(*(three.joint.poses[n][:2] - one.joint.poses[n][:2])) < 0.05


def test_offset_solve_leaves_out_a_nodes_centroid_with_a_close_rival():
    """A node's associated centroid with another of its centroids within
    SPLIT_RADIUS_M in the frame (a split body) is left out of the clock
    offset solve; a rival 1.4 m away (another person) is not a reason."""
    from mmsnap_graph.calibration.joint.multi_refine import (
        SPLIT_RADIUS_M, MultiTargetRefinement, unambiguous_detections)
    from mmsnap_graph.calibration.joint.multi_target import TargetAssociation
    from mmsnap_graph.data.noise import MeasurementNoise
    from mmsnap_graph.data.recording import Detections, NodeData, Recording

    def det(frame, omega):
        k = len(frame)
        return Detections(frame=np.asarray(frame), range_m=np.full(k, 3.0),
                          omega_rad=np.asarray(omega, dtype=float), doppler_mps=np.zeros(k))

    # S1: two centroids 0.1 m apart in frame 0; S2: two 1.4 m apart in frame 1.
    raw = {"S1": det([0, 0, 1], [0.0, 0.1, 0.0]), "S2": det([0, 1, 1], [0.0, 0.0, 1.5])}
    target = {"S1": np.array([0, -1, 0]), "S2": np.array([0, 0, -1])}
    assoc = TargetAssociation(target=target, frame={n: raw[n].frame for n in raw},
                              n_targets=1, n_groups=2, n_breaks=0)
    used = {n: raw[n].select(np.flatnonzero(target[n] >= 0)) for n in raw}
    refined = MultiTargetRefinement(joint=None, mapping=None, association=assoc,
                                    noise=MeasurementNoise(), detections=used)
    rec = Recording(frame_period_s=0.1, nodes={n: NodeData(name=n, centroids=raw[n])
                                               for n in raw})
    out = unambiguous_detections(rec, refined)
    assert SPLIT_RADIUS_M > 0.1
    assert out["S1"].frame.tolist() == [1]
    assert out["S2"].frame.tolist() == [0, 1]
