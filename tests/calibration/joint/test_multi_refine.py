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
    pg = calibrate_recording(proc, method="pose_graph").pose_graph
    with pytest.raises(ValidationError, match="n_rounds"):
        refine_multi(proc, pg, n_rounds=0)


@pytest.mark.slow
def test_more_rounds_do_not_move_a_converged_calibration(point_cloud_recording_3):
    """Rounds stop when the poses stop moving; one round is the old path."""
    meta = {k: v for k, v in point_cloud_recording_3.metadata.items()
            if not k.startswith("centroid_")}
    proc = dataclasses.replace(process_recording(point_cloud_recording_3)[0], metadata=meta)
    pg = calibrate_recording(proc, method="pose_graph").pose_graph
    one = refine_multi(proc, pg, n_rounds=1)
    three = refine_multi(proc, pg, n_rounds=3)
    assert one.joint.success and three.joint.success
    for n in ("S2", "S3"):
        assert np.hypot(*(three.joint.poses[n][:2] - one.joint.poses[n][:2])) < 0.05
