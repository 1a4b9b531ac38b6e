"""``fuse_recording``: a recording fused frame by frame; with
``time_offset_s`` a node whose clock runs late is brought to the reference
clock before fusion."""

import numpy as np
import pytest

from mmsnap_graph.errors import ValidationError
from mmsnap_graph.fusion.recording.sequence import fuse_recording
from mmsnap_graph.sim import network_poses
from mmsnap_graph.sim.clocks import scene_recording, timed_scene


def _rmse(rec, fused):
    frame, state = rec.truth.target(0)
    ok = fused.success
    truth = state[np.searchsorted(frame, fused.frame[ok]), :2]
    return float(np.sqrt(np.mean(np.sum((fused.state[ok, :2] - truth) ** 2, axis=1))))


def test_the_offsets_lower_the_fused_error_and_a_zero_offset_changes_nothing():
    poses = network_poses("C")
    tau = -1.3 * 0.15  # S2 1.3 frames early
    scene = timed_scene(poses, time_offsets_s={"S1": 0.0, "S2": tau}, n_frames=300,
                        kind="walk", rng=np.random.default_rng(4))
    rec = scene_recording(scene)
    plain = fuse_recording(rec, node_poses=poses)
    aligned = fuse_recording(rec, node_poses=poses, time_offset_s={"S2": tau})
    assert _rmse(rec, aligned) < 0.8 * _rmse(rec, plain)
    zero = fuse_recording(rec, node_poses=poses, time_offset_s={"S2": 0.0})
    np.testing.assert_array_equal(zero.state, plain.state)
    with pytest.raises(ValidationError, match="S9"):
        fuse_recording(rec, node_poses=poses, time_offset_s={"S9": 0.1})
