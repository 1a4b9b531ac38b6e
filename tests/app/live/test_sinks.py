"""The sinks of fused live frames: the covariance self-check over a stream
(:class:`~mmsnap_graph.app.live.sinks.SelfCheckSink`, ``mmsnap live`` and
``mmsnap replay``)."""

from __future__ import annotations

import json

import numpy as np

from mmsnap_graph.app.live.sinks import SelfCheckSink
from mmsnap_graph.data.noise import MeasurementNoise
from mmsnap_graph.fusion.options import NetworkCalibration
from mmsnap_graph.fusion.recording.sequence import calibrated_recording, recording_poses
from mmsnap_graph.fusion.stream.frame_stream import STREAM_CONFIG, FrameStream, recording_frames
from mmsnap_graph.io import read_recording
from mmsnap_graph.io.calibration import read_calibration
from mmsnap_graph.io.noise import read_noise


def _self_check(path, scale):
    """The recording streamed with its stored sigmas times ``scale``, every
    update through a SelfCheckSink; (its final report, the lines it logged)."""
    rec = read_recording(path, load_cubes=False)
    cal, noise = read_calibration(path), read_noise(path)
    rec = calibrated_recording(rec, NetworkCalibration(time_offset_s=dict(cal.time_offset_s)))
    sigmas = {n: scale * noise.nodes[n].noise.sigmas for n in rec.node_names}
    noise = {n: MeasurementNoise(range_m=s[0], omega_rad=s[1], doppler_mps=s[2])
             for n, s in sigmas.items()}
    stream = FrameStream(rec.node_names, recording_poses(rec), config=STREAM_CONFIG,
                         noise=noise, pose_covariances={"S2": cal.covariances["S2"]})
    lines = []
    sink = SelfCheckSink(frame_period_s=rec.frame_period_s, prior=STREAM_CONFIG.prior,
                         log=lines.append, command="live")
    for frame, time_s, detections in recording_frames(
            rec, fill_frames=stream.tracker_config.max_misses):
        sink.add(frame, stream.push(time_s, detections))
    sink.close()
    return sink.report(), lines


def test_self_check_sink_is_silent_on_good_sigmas_and_loud_on_small_ones(calibrated_c_file):
    """With the calibrated sigmas: one verdict line, consistent, no warning;
    with 0.3x those sigmas the covariances are too small for the data and the
    sink says so, naming the command; verdict lines only when the verdict
    changes."""
    report, lines = _self_check(calibrated_c_file, 1.0)
    assert report.verdict == "consistent", report.text()
    assert [json.loads(line)["self_check"]["verdict"] for line in lines] == ["consistent"]
    report, lines = _self_check(calibrated_c_file, 0.3)
    assert report.verdict == "over-confident", report.text()
    verdicts = [json.loads(line)["self_check"]["verdict"] for line in lines
                if line.startswith("{")]
    assert verdicts and verdicts[-1] == "over-confident"
    assert all(a != b for a, b in zip(verdicts, verdicts[1:]))  # said on change only
    assert any(line.startswith("mmsnap live: warning: the fused covariances are over-confident")
               for line in lines), lines
    frames = [json.loads(line)["frame"] for line in lines if line.startswith("{")]
    assert np.all(np.diff(frames) > 0)
