"""Replay files of TI's Industrial / Applications Visualizer
(mmsnap_graph.io.ti.replay)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from mmsnap_graph.errors import FileFormatError
from mmsnap_graph.io.ti.point_table import read_point_tables
from mmsnap_graph.io.ti.replay import replay_cfg_text, replay_columns


def _replay(tmp_path, data, demo="SDK Out of Box Demo", name="replay_1.json"):
    path = tmp_path / name
    path.write_text(json.dumps({"cfg": ["frameCfg 0 2 32 0 50 1 0"], "demo": demo,
                                "device": "xWR18xx", "data": data}, indent=4))
    return path


def _frame(k, points, stamp=True):
    out = {"frameData": {"frameNum": k, "numDetectedPoints": len(points),
                         "pointCloud": points, "error": 0}}
    if stamp:
        out["timestamp"] = 1.7e12 + 50.0 * k
    return out


POINTS = [[0.5, 2.0, 0.1, -0.3, 21.5, 55.0, 255], [0.6, 2.1, 0.0, -0.2, 18.0, 54.0, 255]]


def test_replay_columns_and_the_snr_unit_of_the_demo(tmp_path):
    data = [_frame(7, POINTS), _frame(8, []), _frame(9, POINTS[:1])]
    columns, unit = replay_columns(_replay(tmp_path, data))
    assert unit == "db"
    assert columns["frameNum"].tolist() == [7, 7, 9]
    np.testing.assert_array_equal(columns["x (m)"], [0.5, 0.6, 0.5])
    np.testing.assert_array_equal(columns["timestamp (ms)"], 1.7e12 + 50.0 * np.array([7, 7, 9]))
    assert replay_columns(_replay(tmp_path, data, demo="3D People Tracking"))[1] == "linear"
    assert replay_columns(_replay(tmp_path, data, demo=""))[1] is None


def test_a_replay_file_reads_as_a_table(tmp_path):
    data = [_frame(k, POINTS) for k in range(5)]
    cloud = read_point_tables(_replay(tmp_path, data), frame_period_s=0.05)["S1"]
    assert cloud.frame.tolist() == [0, 0, 1, 1, 2, 2, 3, 3, 4, 4]
    np.testing.assert_allclose(cloud.time_s - cloud.time_s[0], 0.05 * cloud.frame, atol=1e-6)
    np.testing.assert_array_equal(cloud.snr_db, [21.5, 18.0] * 5)
    np.testing.assert_array_equal(cloud.noise_db, [55.0, 54.0] * 5)
    linear = [[*p[:4], 10 ** (p[4] / 10), *p[5:]] for p in POINTS]   # people tracking: a ratio
    tracked = read_point_tables(_replay(tmp_path, [_frame(k, linear) for k in range(5)],
                                        demo="3D People Tracking", name="t.json"))["S1"]
    np.testing.assert_allclose(tracked.snr_db, [21.5, 18.0] * 5)
    # Frames without numbers or stamps: numbered in file order.
    bare = [{"frameData": {"pointCloud": POINTS}} for _ in range(3)]
    assert read_point_tables(_replay(tmp_path, bare, name="b.json"))["S1"].frame.tolist() == \
        [0, 0, 1, 1, 2, 2]


@pytest.mark.parametrize("doc, words", [
    ([1, 2], r"a JSON list, not a replay file of TI's visualizer"),
    ({"frames": []}, r"a JSON dict with keys \['frames'\], not a replay file"),
    ({"data": [5]}, r"data\[0\] must be an object with 'frameData'"),
    ({"data": [{"frameData": {"pointCloud": [[1, 2]]}}]}, r"rows of at least 4 numbers"),
    ({"data": [{"frameData": {"pointCloud": [["a", 1, 2, 3]]}}]}, r"list of rows of numbers"),
    ({"data": [{"frameData": {"frameNum": 1.5, "pointCloud": []}}]}, r"frameNum must be a whole"),
    ({"data": [{"frameData": {}, "timestamp": "noon"}]}, r"timestamp must be a number"),
])
def test_a_malformed_replay_file_names_the_field(tmp_path, doc, words):
    path = tmp_path / "r.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(FileFormatError, match=words):
        read_point_tables(path)
    path.write_text("{not json")
    with pytest.raises(FileFormatError, match="not a readable JSON file"):
        read_point_tables(path)


@pytest.mark.parametrize("where, digits, words", [
    ("frameNum", 401, "frameNum must be a whole number within"),
    ("frameNum", 31, "frameNum must be a whole number within"),
    ("frameNum", 5000, "frameNum must be a whole number within"),
    ("timestamp", 401, "timestamp must be a number"),
])
def test_a_huge_number_in_a_replay_file_names_the_field(tmp_path, where, digits, words):
    """Before: math.isfinite(10**400) raised OverflowError, an int64 column of
    10**30 OverflowError, and Python's parser a ValueError beyond 4300 digits."""
    frame = _frame(7, POINTS)
    (frame["frameData"] if where == "frameNum" else frame)[where] = "HUGE"
    path = _replay(tmp_path, [frame, _frame(8, POINTS)])
    path.write_text(path.read_text().replace('"HUGE"', "1" + "0" * (digits - 1)))
    with pytest.raises(FileFormatError, match=words) as info:
        replay_columns(path)
    assert len(str(info.value)) < 300


def test_the_cfg_lines_of_a_replay_file(tmp_path):
    path = _replay(tmp_path, [_frame(0, POINTS)])
    assert replay_cfg_text(path) == "frameCfg 0 2 32 0 50 1 0"
    csv = tmp_path / "t.csv"
    csv.write_text("frame,x,y,z,v\n0,1,2,0,0\n")
    assert replay_cfg_text(csv) is None
    (tmp_path / "bad.json").write_text("{")
    assert replay_cfg_text(tmp_path / "bad.json") is None
    (tmp_path / "nocfg.json").write_text(json.dumps({"cfg": [1, 2], "data": []}))
    assert replay_cfg_text(tmp_path / "nocfg.json") is None
