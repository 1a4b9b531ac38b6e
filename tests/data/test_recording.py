"""Short representations of the recording types: a summary, never the arrays."""

from __future__ import annotations

import numpy as np
import pytest

from mmsnap_graph.data.recording import Detections, NodeData, Recording, Truth
from mmsnap_graph.errors import ValidationError


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


def _detections(frame):
    return Detections(frame=frame, range_m=[1.0, 2.0], omega_rad=[0.0, 0.1],
                      doppler_mps=[0.0, 0.2])


@pytest.mark.parametrize("frame", [["1", "2"], np.array(["1", "2"]), np.array([None, None])],
                         ids=["str list", "str array", "object"])
def test_frame_numbers_that_are_not_numbers_are_a_validation_error(frame):
    with pytest.raises(ValidationError, match="frame"):
        _detections(frame)


def test_uint64_frame_numbers_beyond_int64_are_a_validation_error():
    with pytest.raises(ValidationError, match="frame"):
        _detections(np.array([2**63, 2**63 + 1], dtype=np.uint64))


def test_float_frame_numbers_beyond_int64_are_a_validation_error():
    with pytest.raises(ValidationError, match="frame"):
        _detections([1e19, 2e19])


def test_whole_floats_and_integers_are_still_frame_numbers():
    assert _detections([3.0, 4.0]).frame.tolist() == [3, 4]
    assert _detections(np.array([5, 6], dtype=np.uint32)).frame.tolist() == [5, 6]


@pytest.mark.parametrize("period", ["x", None, True, [0.1], float("nan"), 0.0])
def test_a_bad_frame_period_is_a_validation_error(period):
    from mmsnap_graph.data.recording import Recording
    from mmsnap_graph.errors import ValidationError

    with pytest.raises(ValidationError, match="frame_period_s must be finite and > 0"):
        Recording(frame_period_s=period, nodes={})


@pytest.mark.parametrize("period", [1e-300, 1e-12, 1e-7, 1e5])
def test_a_frame_period_beyond_a_radar_s_is_a_validation_error(period):
    # A 1e-300 s period made process overflow (OverflowError in the scene
    # filters' time windows): a unit mistake, refused where the recording is
    # built or read.
    with pytest.raises(ValidationError, match=r"frame_period_s=.*must be in \[1e-06, 3600\]"):
        Recording(frame_period_s=period, nodes={})


def test_process_and_calibrate_refuse_a_file_with_a_tiny_frame_period(tmp_path, capsys):
    import h5py
    from mmsnap_graph.app.cli import main
    from mmsnap_graph.io import write_recording
    from mmsnap_graph.sim import CLEAN, simulate_recording
    rec = simulate_recording("B", "random", CLEAN, levels=("centroids",), n_frames=20, seed=1)
    path = tmp_path / "rec.h5"
    write_recording(path, rec)
    with h5py.File(path, "r+") as f:
        f.attrs["frame_period_s"] = 1e-300
    for verb in (["process", str(path), "-o", str(tmp_path / "out.h5")],
                 ["calibrate", str(path), "--no-write"]):
        assert main([*verb, "--no-progress"]) in (1, 2)  # a clean error, no traceback
        err = capsys.readouterr().err
        # calibrate reads the file window by window (io.chunks), process whole (data layer):
        # both name the attribute, its bounds and the value
        assert "frame_period_s" in err and "must be" in err and "1e-300" in err, err
