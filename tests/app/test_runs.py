"""What a run does (mmsnap_graph/app/runs.py): one stored calibration for every
command that fuses (fuse, monitor, replay, the batch's fuse step)."""

import json

import numpy as np
import pytest

from mmsnap_graph.app.cli import main
from mmsnap_graph.app.runs import stored_calibration
from mmsnap_graph.data.noise import GaussianPrior, MeasurementNoise
from mmsnap_graph.fusion.recording.sequence import recording_poses
from mmsnap_graph.fusion.stream.frame_stream import FrameStream, recording_frames
from mmsnap_graph.fusion.recording.timing import align_recording
from mmsnap_graph.io import read_recording
from mmsnap_graph.io.calibration import read_calibration
from mmsnap_graph.io.noise import read_noise


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    """Configuration C, 300 frames, calibrated: node poses, /calibration with
    pose covariances and a clock offset of S2, /noise from the data."""
    path = tmp_path_factory.mktemp("runs") / "rec.h5"
    # The clean model: its clocks give S2 an offset for calibrate to find.
    assert main(["simulate", "-c", "C", "-l", "centroids", "-n", "300", "-s", "2",
                 "--model", "clean", "-o", str(path)]) == 0
    assert main(["process", str(path), "--centroids-only", "--no-progress"]) == 0
    assert main(["calibrate", str(path)]) == 0
    return path


def test_stored_calibration_reads_every_part(calibrated):
    rec = read_recording(calibrated, load_cubes=False)
    cal = read_calibration(calibrated)
    noise = read_noise(calibrated)
    stored = stored_calibration(calibrated, rec.node_names)
    assert stored.node_poses is None  # the recording's own poses
    assert set(stored.pose_covariances) == {"S2"}
    np.testing.assert_array_equal(stored.pose_covariances["S2"], cal.covariances["S2"])
    assert stored.time_offset_s == {"S2": pytest.approx(cal.time_offset_s["S2"])}
    assert stored.noise == {n: noise.nodes[n].noise for n in rec.node_names}
    pooled = stored_calibration(calibrated, rec.node_names, per_node_noise=False).noise
    assert pooled == noise.pooled()
    given = stored_calibration(calibrated, rec.node_names, sigmas=(0.1, 0.2, 0.3),
                               pose_covariances=False, time_offsets=False)
    assert given.noise == MeasurementNoise(range_m=0.1, omega_rad=0.2, doppler_mps=0.3)
    assert given.pose_covariances is None and given.time_offset_s is None
    assert given.text[1] == "poses exact; clocks as recorded"
    json_path = calibrated.with_name("rec.calibration.json")
    from_json = stored_calibration(calibrated, rec.node_names, calibration_json=json_path)
    assert set(from_json.node_poses) == set(rec.node_names)


def test_monitor_uses_the_stored_noise_poses_and_clocks(calibrated, tmp_path, capsys):
    """Before: the monitor ran with the recording's metadata sigmas (the
    simulator's) and the clocks as recorded, whatever `calibrate` stored."""
    capsys.readouterr()
    out = tmp_path / "monitor.json"
    assert main(["monitor", str(calibrated), "--json-out", str(out)]) == 0
    text = capsys.readouterr().out
    pooled = read_noise(calibrated).pooled()
    assert "sigmas from /noise" in text and "clock offsets applied: S2" in text
    assert f"noise (range {pooled.range_m:g} m, omega {pooled.omega_rad:g} rad)" in text
    rec = read_recording(calibrated, load_cubes=False)
    meta = rec.metadata
    assert not np.isclose(pooled.omega_rad, float(meta.get("centroid_omega_std", np.nan)))
    # The same run by hand from the stored parts.
    from mmsnap_graph.calibration.monitor.decalibration import DEFAULT_THRESHOLD, monitor_recording

    cal = read_calibration(calibrated)
    expected = monitor_recording(align_recording(rec, dict(cal.time_offset_s)),
                                 node_covariances={"S2": cal.covariances["S2"]},
                                 noise=pooled, threshold=DEFAULT_THRESHOLD,
                                 recalibration_s=15.0)
    got = json.loads(out.read_text())
    assert got["n_frames"] == expected.frame.size
    assert len(got["changes"]) == len(expected.changes)


def _replay_rows(path, tmp_path, *extra):
    out = tmp_path / "frames.jsonl"
    assert main(["replay", str(path), "--summary", "-o", str(out), *extra]) == 0
    return [json.loads(line) for line in out.read_text().splitlines()]


def test_replay_uses_the_stored_noise_pose_covariances_and_clocks(calibrated, tmp_path, capsys):
    """Before: replay fused with the paper's sigmas, exact poses and the
    clocks as recorded. Now it equals a FrameStream given the stored parts."""
    rows = _replay_rows(calibrated, tmp_path)
    assert "clock offsets applied: S2" in capsys.readouterr().err
    rec = read_recording(calibrated, load_cubes=False)
    cal = read_calibration(calibrated)
    noise = read_noise(calibrated)
    aligned = align_recording(rec, dict(cal.time_offset_s))
    stream = FrameStream(rec.node_names, recording_poses(rec), prior=GaussianPrior(),
                         noise={n: noise.nodes[n].noise for n in rec.node_names},
                         pose_covariances={"S2": cal.covariances["S2"]})
    fill = stream.tracker_config.max_misses
    expected = [(f, stream.push(t, d)) for f, t, d in recording_frames(aligned, fill_frames=fill)]
    assert [r["frame"] for r in rows] == [f for f, _ in expected]
    for r, (_, u) in zip(rows, expected):
        np.testing.assert_allclose(np.asarray(r["state"]).reshape(-1, 4), u.state, atol=1e-9)
        np.testing.assert_allclose(np.asarray(r["covariance"]).reshape(-1, 4, 4), u.covariance,
                                   rtol=1e-9, atol=1e-15)
    # Each stored part changes the answer (so the comparison can fail).
    plain = FrameStream(rec.node_names, recording_poses(rec), prior=GaussianPrior())
    first = next(u for _, u in expected if len(u))
    frame0 = next(f for f, u in expected if len(u))
    _, t0, d0 = next(x for x in recording_frames(aligned, fill_frames=fill) if x[0] == frame0)
    assert not np.allclose(plain.push(t0, d0).covariance, first.covariance)
