"""What a run does (mmsnap_graph/app/runs.py): one stored calibration for every
command that fuses (fuse, monitor, replay, the batch's fuse step)."""

import json

import numpy as np
import pytest

from _cli import mmsnap, simulated
from mmsnap_graph.app.cli import main
from mmsnap_graph.app.runs import stored_calibration
from mmsnap_graph.data.noise import GaussianPrior, MeasurementNoise
from mmsnap_graph.fusion.recording.sequence import recording_poses
from mmsnap_graph.fusion.stream.frame_stream import FrameStream, recording_frames
from mmsnap_graph.fusion.recording.timing import align_recording
from mmsnap_graph.io import read_recording
from mmsnap_graph.io.calibration import read_calibration
from mmsnap_graph.io.noise import read_noise
from _fusion import stream_config


def test_stored_calibration_reads_every_part(calibrated_c_file):
    rec = read_recording(calibrated_c_file, load_cubes=False)
    cal = read_calibration(calibrated_c_file)
    noise = read_noise(calibrated_c_file)
    stored = stored_calibration(calibrated_c_file, rec.node_names)
    assert stored.node_poses is None  # the recording's own poses
    assert set(stored.pose_covariances) == {"S2"}
    np.testing.assert_array_equal(stored.pose_covariances["S2"], cal.covariances["S2"])
    assert stored.time_offset_s == {"S2": pytest.approx(cal.time_offset_s["S2"])}
    assert stored.noise == {n: noise.nodes[n].noise for n in rec.node_names}
    pooled = stored_calibration(calibrated_c_file, rec.node_names, per_node_noise=False).noise
    assert pooled == noise.pooled()
    given = stored_calibration(calibrated_c_file, rec.node_names, sigmas=(0.1, 0.2, 0.3),
                               pose_covariances=False, time_offsets=False)
    assert given.noise == MeasurementNoise(range_m=0.1, omega_rad=0.2, doppler_mps=0.3)
    assert given.pose_covariances is None and given.time_offset_s is None
    assert given.text[1] == "poses exact; clocks as recorded"
    json_path = calibrated_c_file.with_name("rec.calibration.json")
    from_json = stored_calibration(calibrated_c_file, rec.node_names, calibration_json=json_path)
    assert set(from_json.node_poses) == set(rec.node_names)


def test_monitor_uses_the_stored_noise_poses_and_clocks(calibrated_c_file, tmp_path, capsys):
    """Before: the monitor ran with the recording's metadata sigmas (the
    simulator's) and the clocks as recorded, whatever `calibrate` stored."""
    capsys.readouterr()
    out = tmp_path / "monitor.json"
    assert main(["monitor", str(calibrated_c_file), "--json-out", str(out)]) == 0
    text = capsys.readouterr().out
    pooled = read_noise(calibrated_c_file).pooled()
    assert "sigmas from /noise" in text and "clock offsets applied: S2" in text
    assert f"noise range {pooled.range_m:.3g} m, omega {pooled.omega_rad:.3g} rad" in text
    rec = read_recording(calibrated_c_file, load_cubes=False)
    meta = rec.metadata
    assert not np.isclose(pooled.omega_rad, float(meta.get("centroid_omega_std", np.nan)))
    # The same run by hand from the stored parts.
    from mmsnap_graph.calibration.monitor.decalibration import DEFAULT_THRESHOLD, monitor_recording

    cal = read_calibration(calibrated_c_file)
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


def test_replay_uses_the_stored_noise_pose_covariances_and_clocks(calibrated_c_file, tmp_path,
                                                                  capsys):
    """Before: replay fused with the paper's sigmas, exact poses and the
    clocks as recorded. Now it equals a FrameStream given the stored parts."""
    rows = _replay_rows(calibrated_c_file, tmp_path)
    assert "clock offsets applied: S2" in capsys.readouterr().err
    rec = read_recording(calibrated_c_file, load_cubes=False)
    cal = read_calibration(calibrated_c_file)
    noise = read_noise(calibrated_c_file)
    from mmsnap_graph.fusion.options import NetworkCalibration
    from mmsnap_graph.fusion.recording.sequence import calibrated_recording
    from mmsnap_graph.fusion.stream.frame_stream import STREAM_CONFIG

    depth = float(cal.range_offset_m)
    aligned = calibrated_recording(rec, NetworkCalibration(
        time_offset_s=dict(cal.time_offset_s), range_offset_m=depth if np.isfinite(depth) else None))
    stream = FrameStream(rec.node_names, recording_poses(rec), config=STREAM_CONFIG,
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
    plain = FrameStream(rec.node_names, recording_poses(rec), config=stream_config(prior=GaussianPrior()))
    first = next(u for _, u in expected if len(u))
    frame0 = next(f for f, u in expected if len(u))
    _, t0, d0 = next(x for x in recording_frames(aligned, fill_frames=fill) if x[0] == frame0)
    assert not np.allclose(plain.push(t0, d0).covariance, first.covariance)


@pytest.mark.slow
def test_process_and_calibrate_at_once_keep_both_updates(tmp_path):
    """Before: each rewrote the file from the copy it read at its start; the
    one finishing last silently dropped the other's update (on main c862145
    with 2000 frames: /calibration written, the node poses gone)."""
    recording = simulated(tmp_path / "rec.h5", 2000)
    before = read_recording(recording)
    assert all(before.nodes[n].tracks is None for n in before.node_names)
    procs = [mmsnap("process", str(recording), "--centroids-only", "--no-progress"),
             mmsnap("calibrate", str(recording), "--method", "pose_graph", "--source",
                    "centroids")]
    outs = [p.communicate(timeout=600) for p in procs]
    assert [p.returncode for p in procs] == [0, 0], outs
    after = read_recording(recording)
    cal = read_calibration(recording)
    for name in after.node_names:
        assert after.nodes[name].tracks is not None, f"{name}: process's tracks were lost"
        if name in cal.poses:
            np.testing.assert_allclose(after.nodes[name].pose, cal.poses[name],
                                       err_msg=f"{name}: calibrate's pose was lost")
    assert len(cal.poses) >= 2
    assert not list(recording.parent.glob(".rec.h5.*")), "lock or temporary files left"


def test_fuse_reads_the_range_offset_and_runs_no_estimator(calibrated_c_file, tmp_path,
                                                            monkeypatch, capsys):
    """Before: `mmsnap fuse --calibration JSON` read the whole recording and
    ran the range-offset estimator at the JSON's poses (runs.py
    range_offset_for_poses), against fuse's bounded memory. Now it reads
    what `mmsnap noise --calibration` stored, or adds none and says so."""
    from mmsnap_graph.calibration.noise import depth

    rec = read_recording(calibrated_c_file, load_cubes=False)
    poses = {n: [float(v) + 0.01 for v in p] for n, p in rec.truth.node_poses.items()}
    cal = tmp_path / "moved.json"
    cal.write_text(json.dumps({"nodes": {n: {"pose": p} for n, p in poses.items()}}))

    def refuse(*args, **kwargs):
        raise AssertionError("fuse ran the range-offset estimator")
    monkeypatch.setattr(depth, "range_offset_at_poses", refuse)
    capsys.readouterr()
    assert main(["fuse", str(calibrated_c_file), "-o", str(tmp_path / "f.h5"), "--no-progress",
                 "--calibration", str(cal)]) == 0
    assert "none was estimated at these poses: none added" in capsys.readouterr().out


def test_a_json_of_fixed_poses_brings_the_range_offset_the_data_identify(calibrated_c_file,
                                                                          tmp_path, capsys):
    """Before: fusing at poses given by a JSON without a range offset added
    none, and centroids 0.08 m short in range (a body's near side) biased
    every fused position by about that much. Now the offset is estimated at
    those poses from the cross-node residuals and added; a JSON of the
    calibration's own poses (which took any depth in) adds none."""
    from mmsnap_graph.evaluation.metrics import truth_reference
    from mmsnap_graph.io import write_recording
    from mmsnap_graph.io.fused import read_fused

    from _cli import with_centroids

    rec = read_recording(calibrated_c_file, load_cubes=False)
    for i in range(len(rec.node_names)):
        rec = with_centroids(rec, i, lambda r, w, v: r.__isub__(0.08))
    path = write_recording(tmp_path / "short.h5", rec)
    poses = rec.truth.node_poses
    true_json = tmp_path / "true.json"
    true_json.write_text(json.dumps({"nodes": {n: {"pose": [float(v) for v in p]}
                                               for n, p in poses.items()}}))
    stored = stored_calibration(calibrated_c_file, rec.node_names, calibration_json=true_json)
    assert stored.range_offset_m is None or abs(stored.range_offset_m) < 0.02
    assert "`mmsnap noise rec.h5 --calibration true.json` estimates them" in stored.text[1]
    # Fusion reads the offset; `mmsnap noise --calibration` estimates it with
    # the noise at those poses and stores both.
    stored = stored_calibration(path, rec.node_names, calibration_json=true_json)
    assert stored.range_offset_m is None and "none added" in stored.text[1]
    assert "estimates them and the range offset at these poses" in stored.text[1]
    assert main(["noise", str(path), "--calibration", str(true_json)]) == 0
    stored = stored_calibration(path, rec.node_names, calibration_json=true_json)
    assert stored.range_offset_m == pytest.approx(0.08, abs=0.02)
    assert "range offset at these poses +0.0" in stored.text[1]
    capsys.readouterr()
    assert main(["fuse", str(path), "--no-progress", "--calibration", str(true_json)]) == 0
    assert "range offset at these poses" in capsys.readouterr().out
    fused = read_fused(path)
    ok = np.asarray(fused.success, bool)
    ref, _ = truth_reference(fused.frame[ok], fused.state[ok, :2], rec.truth.frame,
                             rec.truth.target_id, rec.truth.state)
    bias = np.nanmean(fused.state[ok, :2] - ref[:, :2], axis=0)
    assert np.all(np.abs(bias) < 0.02), bias
    own = calibrated_c_file.with_name("rec.calibration.json")
    mine = stored_calibration(calibrated_c_file, rec.node_names, calibration_json=own)
    assert mine.range_offset_m is None and "range offset" not in mine.text[1]


def test_nominal_texts_word_each_cause():
    """What `mmsnap calibrate` and `mmsnap monitor` warn of: the real
    recording's S2 (1.738, 1.624) m, 86.24 deg against nominal poses."""
    from mmsnap_graph.app.runs import nominal_texts
    from mmsnap_graph.evaluation.nominal import nominal_metadata

    def texts(s2_deg, pose, source="room_pose"):
        md = {**nominal_metadata("S1", [0, 0, 0], source),
              **nominal_metadata("S2", [1.7, 1.65, np.deg2rad(s2_deg)], source)}
        return nominal_texts(md, {"S1": np.zeros(3), "S2": np.array(pose)}, reference="S1")

    real = [1.738, 1.624, np.deg2rad(86.24)]
    assert texts(90, real) == []
    (text,) = texts(180, real, source="pose")
    assert text.startswith("S2 was calibrated 0.05 m and -93.8 deg from its nominal pose (--pose: "
                           "x 1.70 m, y 1.65 m, heading 180.0 deg in S1's frame): the headings "
                           "differ by about 90 deg: was the boresight's direction given? The "
                           "heading is the direction of the antenna array axis")
    (text,) = texts(90, [0.245, 0.178, np.deg2rad(5.46)])
    assert "its points were already in a frame common to both (a room-frame log imported " \
           "without --room-pose for this node?)" in text
    (text,) = nominal_texts({}, {"S1": np.zeros(3), "S2": np.array([0.245, 0.178, 0.095])},
                            reference="S1")
    assert text.startswith("S1 and S2 were calibrated 0.30 m and +5.4 deg apart: two radars at "
                           "one place looking the same way?")


@pytest.mark.slow
def test_real_recording_without_room_poses_warns_at_calibrate(tmp_path, capsys):
    """A room-frame log imported without --room-pose: S2 calibrated at S1's
    place (0.36 m, -12 deg away) with 6-7 cm sigmas and no word; now a
    warning naming the likely cause."""
    from _shared import DATA
    real = DATA / "real" / "darksz"
    out = tmp_path / "mt.h5"
    assert main(["import", "table", "--node", f"S1={real / 'multiple_tracking_S1.csv'}",
                 "--node", f"S2={real / 'multiple_tracking_S2.csv'}", "--frame-period", "0.05",
                 "--mount", "S1=0.8,0", "--mount", "S2=1.1,0", "--height-band", "0.2,2.0",
                 "--pose", "S1=0,0,0", "--pose", "S2=1.7,1.65,90", "-o", str(out)]) == 0
    assert main(["process", str(out)]) == 0
    capsys.readouterr()
    assert main(["calibrate", str(out)]) == 0
    err = capsys.readouterr().err
    assert "mmsnap calibrate: warning: S2 was calibrated 2.62 m and -102.3 deg from its " \
           "nominal pose (--pose: x 1.70 m, y 1.65 m, heading 90.0 deg in S1's frame): it was " \
           "calibrated at the reference's own place and heading" in err
