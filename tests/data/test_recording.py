"""Short representations of the recording types: a summary, never the arrays."""

from __future__ import annotations

import numpy as np

from mmsnap_graph.data.recording import Detections, NodeData, Recording, Truth


def _recording(k: int) -> Recording:
    frame = np.arange(k)
    det = Detections(frame=frame, range_m=np.full(k, 3.0), omega_rad=np.zeros(k),
                     doppler_mps=np.zeros(k))
    truth = Truth(frame=frame, target_id=np.zeros(k, int), state=np.zeros((k, 4)))
    nodes = {"S1": NodeData(name="S1", pose=np.zeros(3), centroids=det),
             "S2": NodeData(name="S2", centroids=det)}
    return Recording(frame_period_s=0.05, nodes=nodes, truth=truth, metadata={"seed": 1})


def test_repr_is_a_summary_whose_size_does_not_grow_with_the_data():
    short, long = repr(_recording(10)), repr(_recording(100_000))
    assert len(long) < 600 and len(long) - len(short) < 30
    assert "Detections(100000 rows, frames 0-99999)" in long
    assert "pose unknown" in long and "0.000 m" in long
    assert "Truth(100000 rows, frames 0-99999, 1 targets)" in long
    assert "metadata keys: ['seed']" in long


def test_empty_detections_repr():
    det = Detections(frame=np.zeros(0, int), range_m=np.zeros(0), omega_rad=np.zeros(0),
                     doppler_mps=np.zeros(0))
    assert repr(det) == "Detections(0 rows)"
