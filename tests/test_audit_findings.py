"""Issue 13, finding "Scalar options and configs are not type-checked (...
string frame numbers ...; uint64 frames >= 2^63 wrap)": found at the
public API by the audit of the issue (these tests failed before): the file
reader refused such frames (tests/test_reliability_runs.py) but
``Detections`` (and every other user of the private ``int_array`` helper)
raised an untyped TypeError for strings and wrapped uint64 >= 2^63.
"""

from __future__ import annotations

import numpy as np
import pytest

from mmsnap_graph.data.recording import Detections
from mmsnap_graph.errors import ValidationError


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
