"""``mmsnap live --refine``'s sink (app/live/refine.py): the refinement in
its own process, its updates applied to the stream at frame boundaries,
printed as JSON lines and stored as a calibration JSON."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from mmsnap_graph.app.live.driver import replayed_frame
from mmsnap_graph.app.live.refine import RefineSink
from mmsnap_graph.data.noise import declared_noise
from mmsnap_graph.errors import ValidationError
from mmsnap_graph.fusion.stream.frame_stream import STREAM_CONFIG, FrameStream
from mmsnap_graph.io.calibration import read_calibration_json

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "calibration"))
from test_online import NET, PERIOD, _bumped  # noqa: E402


def _frames(rec):
    cents = {n: rec.nodes[n].centroids for n in rec.node_names}
    frames = max(int(c.frame.max()) for c in cents.values()) + 1
    cuts = {n: np.searchsorted(c.frame, np.arange(frames + 1)) for n, c in cents.items()}
    for f in range(frames):
        yield f, {n: cents[n].measurements[cuts[n][f]:cuts[n][f + 1]] for n in rec.node_names}


@pytest.mark.slow
def test_the_sink_refines_the_stream_and_stores_each_change(tmp_path):
    rec = _bumped(1)                 # S3 moves 10 cm along x at 60 s
    names = list(NET)
    poses = np.array([NET[n] for n in names])
    stream = FrameStream(names, poses, config=STREAM_CONFIG)
    lines, path = [], tmp_path / "refined.json"
    sink = RefineSink(stream, names, poses, frame_period_s=PERIOD,
                      noise=declared_noise(rec.metadata), json_path=path, log=lines.append,
                      window_s=30.0)
    seen = []                        # the stream's poses at each slot
    for f, cents in _frames(rec):
        seen.append(stream.node_poses.copy())
        sink.write(replayed_frame(f, f * PERIOD, cents, stream.push(f * PERIOD, cents)))
        if f % 100 == 99:            # as if in real time: the refinement keeps up
            sink.sync()
    sink.close()
    assert not sink.error and sink.summary["windows"] == 3   # the one of the move restarts
    got = [json.loads(line) for line in lines]
    assert all(g["type"] == "calibration" for g in got)
    reasons = [g["reason"] for g in got]
    assert "change" in reasons and "recalibrated" in reasons and reasons.count("window") >= 3
    recal = got[reasons.index("recalibrated")]
    assert recal["nodes"] == ["S3"]
    # applied at frame boundaries: the stream's poses moved after the slot an update names
    moved = [k for k in range(1, len(seen)) if not np.array_equal(seen[k], seen[k - 1])]
    published = [np.array([g["poses"][n] for n in names]) for g in got if g["reason"] != "change"]
    assert moved and all(any(np.allclose(seen[k], p, atol=1e-12) for p in published)
                         for k in moved)
    np.testing.assert_allclose(stream.node_poses,
                               [got[-1]["poses"][n] for n in names], rtol=0, atol=1e-12)
    truth_after = np.asarray(NET["S3"]) + [0.1, 0.0, 0.0]
    assert np.hypot(*(stream.node_poses[2, :2] - truth_after[:2])) < 0.03
    stored = read_calibration_json(path)
    np.testing.assert_allclose(stored.poses["S3"], got[-1]["poses"]["S3"], atol=1e-9)


def test_a_bad_window_is_the_commands_error_not_the_childs():
    names = list(NET)
    poses = np.array([NET[n] for n in names])
    with pytest.raises(ValidationError, match="--refine-window-s"):
        RefineSink(FrameStream(names, poses), names, poses, frame_period_s=PERIOD,
                   window_s=0.5)
