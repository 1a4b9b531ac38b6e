"""The decalibration monitor (calibration.monitor) on bumped simulated recordings
(sim.bump): detection delay, attribution, re-calibrated pose, false alarms."""

from __future__ import annotations

from mmsnap_graph.errors import MissingStepError

import numpy as np
import pytest

from factors.models import measurement_model
from mmsnap_graph.calibration.monitor.decalibration import (
    DEFAULT_THRESHOLD,
    DecalibrationMonitor,
    monitor_recording,
    recording_measurements,
)
from mmsnap_graph.data.noise import MeasurementNoise
from mmsnap_graph.errors import ValidationError
from mmsnap_graph.sim import simulate_recording
from mmsnap_graph.sim.bump import simulate_bumped_recording
from mmsnap_graph.sim import CLEAN, SimulationOptions

NOISE = MeasurementNoise(range_m=0.05, omega_rad=0.08, doppler_mps=0.10)   # sim.CENTROID_NOISE
BUMP_TIME_S = 45.0
N_FRAMES = 540          # 45 s before the bump, 36 s after: 20 s to detect + 15 s to re-calibrate
TRIANGLE = {"S1": (0.0, 0.0, 0.0), "S2": (0.0, 7.0, np.pi), "S3": (-3.5, 3.5, -np.pi / 2)}


def _bumped(network, node, bump, seed):
    return simulate_bumped_recording(network, "random", physics=None, node=node, bump=bump,
                                     bump_time_s=BUMP_TIME_S, n_frames=N_FRAMES, seed=seed)


def _bumped_truth(rec) -> np.ndarray:
    return np.array([rec.metadata[k] for k in ("bumped_x_m", "bumped_y_m", "bumped_phi_rad")])


def _tangent_error(pose, truth) -> np.ndarray:
    """``pose`` minus ``truth`` in ``pose``'s body tangent (the covariance's frame)."""
    d = truth[:2] - pose[:2]
    c, s = np.cos(pose[2]), np.sin(pose[2])
    dphi = (truth[2] - pose[2] + np.pi) % (2 * np.pi) - np.pi
    return -np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1], dphi])


# ------------------------------------------------------------------ simulator
def test_bumped_recording_moves_only_that_node_from_the_bump_frame():
    plain = simulate_recording("C", "random", SimulationOptions(physics=None, known_poses=True),
                               levels=("centroids",), n_frames=120, seed=4)
    rec = simulate_bumped_recording("C", "random", physics=None, node="S2", bump=(0.1, -0.05, 0.03),
                                    bump_time_s=9.0, n_frames=120, seed=4)
    k = rec.metadata["bump_frame"]
    assert k == 60 and rec.metadata["bump_node"] == "S2"
    np.testing.assert_allclose(_bumped_truth(rec), [0.1, 6.95, np.pi + 0.03])
    np.testing.assert_array_equal(rec.nodes["S1"].centroids.measurements,
                                  plain.nodes["S1"].centroids.measurements)
    before, after = rec.nodes["S2"].centroids, plain.nodes["S2"].centroids
    np.testing.assert_array_equal(before.measurements[before.frame < k],
                                  after.measurements[after.frame < k])
    assert not np.allclose(before.measurements[before.frame >= k],
                           after.measurements[after.frame >= k])
    # after the bump the node measures the truth from the bumped pose (noise 5 cm / 0.08 rad)
    fr = before.frame[before.frame >= k]
    h, _ = measurement_model(rec.truth.state[fr], _bumped_truth(rec))
    resid = before.measurements[before.frame >= k] - h
    assert abs(np.mean(resid[:, 0])) < 0.02 and abs(np.std(resid[:, 0]) - 0.05) < 0.01
    np.testing.assert_allclose(rec.nodes["S2"].pose, [0.0, 7.0, np.pi])     # the old calibration
    with pytest.raises(ValidationError, match="bump_time_s"):
        simulate_bumped_recording("C", physics=None, node="S2", bump_time_s=100.0, n_frames=100)
    with pytest.raises(ValidationError, match="node"):
        simulate_bumped_recording("C", physics=None, node="S9", n_frames=100)


# ------------------------------------------------------------------ targets
@pytest.mark.slow
@pytest.mark.parametrize("bump", [(0.1, 0.0, 0.0), (0.0, 0.0, np.deg2rad(2.0))],
                         ids=["10cm", "2deg"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_bump_detected_within_20_s_and_recalibrated_within_3_sigma(bump, seed):
    """Configuration C (S2 faces S1 across 7 m), the 10 cm bump across S2's
    line of sight (its weak direction). Measured delays (bench_monitor.py):
    10 cm 5.7-11.6 s, 2 deg 2.7-7.5 s on seeds 0-3."""
    rec = _bumped("C", "S2", bump, seed)
    res = monitor_recording(rec)
    assert res.noise == NOISE                                  # from the recording's metadata
    assert len(res.changes) == 1, [(c.node, c.time_s) for c in res.changes]
    change = res.changes[0]
    assert change.node == "S2"
    delay = change.detection_time_s - rec.metadata["bump_time_s"]
    assert 0.0 <= delay <= 20.0
    assert abs(change.time_s - rec.metadata["bump_time_s"]) <= 5.0
    (recal,) = res.recalibrations
    assert recal.fit.success and recal.node == "S2"
    err = _tangent_error(recal.fit.pose, _bumped_truth(rec))
    sd = np.sqrt(np.diag(recal.fit.covariance))
    assert np.all(np.abs(err) <= 3.0 * sd), (err, sd)
    assert np.all(sd < [0.1, 0.1, np.deg2rad(2.0)])            # informative, not a shrug
    np.testing.assert_allclose(res.poses["S2"], recal.fit.pose)


@pytest.mark.slow
@pytest.mark.parametrize("node, bump", [("S3", (0.1, 0.0, 0.0)),
                                        ("S1", (0.0, 0.0, np.deg2rad(2.0)))])
def test_three_nodes_name_the_node_that_moved(node, bump):
    """With three nodes every node is tested; the reference S1 moving is
    re-estimated in the frame the other two still define."""
    rec = _bumped(TRIANGLE, node, bump, 1)
    res = monitor_recording(rec)
    assert [c.node for c in res.changes] == [node]
    assert res.changes[0].detection_time_s - rec.metadata["bump_time_s"] <= 20.0
    (recal,) = res.recalibrations
    err = _tangent_error(recal.fit.pose, _bumped_truth(rec))
    assert np.all(np.abs(err) <= 3.0 * np.sqrt(np.diag(recal.fit.covariance)))


@pytest.mark.slow
def test_no_false_alarm_on_ten_clean_minutes():
    """4,000 clean frames (10 min) of configuration C: no change, the largest
    statistic below the threshold (one hour per network: benchmarks/bench_monitor.py)."""
    rec = simulate_recording("C", "random", SimulationOptions(physics=None, known_poses=True),
                             levels=("centroids",), n_frames=4000, seed=21)
    res = monitor_recording(rec)
    assert res.changes == () and res.recalibrations == ()
    tested = res.statistics[:, 1]
    assert np.isfinite(tested).sum() > 3900
    assert np.nanmax(tested) < DEFAULT_THRESHOLD
    assert np.all(np.isnan(res.statistics[:, 0]))              # two nodes: S1 is the frame


# ------------------------------------------------------------------ streaming API
def test_frame_by_frame_updates_equal_the_batch_run():
    rec = simulate_bumped_recording("C", "random", physics=None, node="S2", bump=(0.25, 0.0, 0.05),
                                    bump_time_s=15.0, n_frames=260, seed=5)
    _, z = recording_measurements(rec)
    tight = {"S2": np.diag([0.01, 0.01, 0.003]) ** 2}
    batch = DecalibrationMonitor(rec.truth.node_poses, noise=NOISE, node_covariances=tight,
                                 recalibration_s=6.0)
    ups_batch = batch.update_frames(z)
    stream = DecalibrationMonitor(rec.truth.node_poses, noise=NOISE, node_covariances=tight,
                                  recalibration_s=6.0)
    ups = [stream.update(dict(zip(rec.node_names, (None if np.isnan(r[0]) else r for r in row))),
                         time_s=k * 0.15)
           for k, row in enumerate(z)]
    assert len(batch.changes) >= 1 and batch.changes[0].node == "S2"
    assert [(c.node, c.frame, c.detection_frame) for c in stream.changes] == \
        [(c.node, c.frame, c.detection_frame) for c in batch.changes]
    assert [u.frame for u in ups] == [u.frame for u in ups_batch] == list(range(260))
    np.testing.assert_allclose([u.statistics["S2"] for u in ups],
                               [u.statistics["S2"] for u in ups_batch], rtol=1e-8)
    np.testing.assert_allclose(stream.poses["S2"], batch.poses["S2"], rtol=1e-8)
    assert batch.recalibrations and batch.recalibrations[0].fit.success


def test_monitor_validates_its_inputs():
    poses = {"S1": (0, 0, 0), "S2": (0, 7, np.pi)}
    with pytest.raises(ValidationError, match="at least two"):
        DecalibrationMonitor({"S1": (0, 0, 0)})
    with pytest.raises(ValidationError, match="node_poses\\[S2\\]"):
        DecalibrationMonitor({"S1": (0, 0, 0), "S2": (0, 7)})
    with pytest.raises(ValidationError, match="threshold"):
        DecalibrationMonitor(poses, threshold=-1.0)
    with pytest.raises(ValidationError, match="node_covariances"):
        DecalibrationMonitor(poses, node_covariances={"S2": -np.eye(3)})
    mon = DecalibrationMonitor(poses, noise=NOISE)
    with pytest.raises(ValidationError, match="shape"):
        mon.update(np.zeros((3, 3)))
    with pytest.raises(ValidationError, match="range > 0"):
        mon.update([[-1.0, 0.0, 0.0], [3.0, 0.0, 0.0]])
    with pytest.raises(ValidationError, match="no such node"):
        mon.update({"S7": (3.0, 0.0, 0.0)})
    up = mon.update({"S1": (3.5, 0.0, 0.0), "S2": None})        # S2 unseen: not tested
    assert up.frame == 0 and np.isnan(up.statistics["S2"]) and up.change is None
    rec = simulate_recording("C", options=CLEAN, levels=("centroids",), n_frames=20, seed=1)  # poses unknown
    with pytest.raises(MissingStepError, match="no pose") as info:  # a data error, as in fusion
        monitor_recording(rec)
    assert info.value.step == "calibrate"


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="configuration A, 10 cm along x (S2's array axis, the "
                   "S1-S2 baseline): not detected within 20 s; largest statistic after the bump "
                   "27-30 against the threshold 35.4 on seeds 0-3 (benchmarks/bench_monitor.py; "
                   "this is seed 0; with the bump at 45 s seed 0 is detected): the move is mostly a turn about the small common area, which the walk "
                   "hardly separates from the old pose")
def test_configuration_a_bump_along_the_baseline_detected_within_20_s():
    rec = simulate_bumped_recording("A", "random", physics=None, node="S2", bump=(0.1, 0.0, 0.0),
                                    bump_time_s=60.0, n_frames=800, seed=0)
    res = monitor_recording(rec)
    assert [c.node for c in res.changes] == ["S2"]
    assert res.changes[0].detection_time_s - rec.metadata["bump_time_s"] <= 20.0


def test_monitor_recording_in_blocks_with_a_bar_equals_one_batch_run(capsys):
    """The progress bar steps update_frames over blocks of frames: the change
    points, statistics and poses are those of one call over every frame."""
    rec = simulate_bumped_recording("C", "random", physics=None, node="S2", bump=(0.25, 0.0, 0.05),
                                    bump_time_s=15.0, n_frames=260, seed=5)
    tight = {"S2": np.diag([0.01, 0.01, 0.003]) ** 2}
    result = monitor_recording(rec, node_poses=rec.truth.node_poses, noise=NOISE,
                               node_covariances=tight, recalibration_s=6.0, progress=True)
    assert "monitor" in capsys.readouterr().err  # the bar, on stderr
    _, z = recording_measurements(rec)
    batch = DecalibrationMonitor(rec.truth.node_poses, noise=NOISE, node_covariances=tight,
                                 recalibration_s=6.0, frame_period_s=rec.frame_period_s)
    ups = batch.update_frames(z, np.arange(len(z)) * rec.frame_period_s)
    assert result.changes and [(c.node, c.frame) for c in result.changes] == \
        [(c.node, c.frame) for c in batch.changes]
    np.testing.assert_allclose(result.statistics[:, 1], [u.statistics["S2"] for u in ups],
                               rtol=1e-8)
    np.testing.assert_allclose(result.poses["S2"], batch.poses["S2"], rtol=1e-8)
    monitor_recording(rec, node_poses=rec.truth.node_poses, noise=NOISE)
    assert capsys.readouterr().err == ""


@pytest.mark.parametrize("kw", [dict(windows_s=[1e308]), dict(windows_s=[3.0, 1e9]),
                                dict(recalibration_s=1e308), dict(recalibration_s=1e7)])
def test_a_span_longer_than_any_recording_is_a_validation_error(kw):
    from mmsnap_graph.calibration.monitor.decalibration import DecalibrationMonitor
    from mmsnap_graph.errors import ValidationError

    poses = {"S1": np.zeros(3), "S2": np.array([1.0, 2.0, 0.5])}
    name = next(iter(kw))
    with pytest.raises(ValidationError, match=f"{name}=.*at most 1e\\+07 frames"):
        DecalibrationMonitor(poses, frame_period_s=0.1, **kw)


def test_monitor_cli_names_a_huge_recalibration_span(tmp_path, capsys):
    from mmsnap_graph.app.cli import main

    path = tmp_path / "rec.h5"
    assert main(["simulate", "-c", "B", "-n", "40", "-l", "centroids", "--known-poses",
                 "-o", str(path), "--no-progress"]) == 0
    assert main(["monitor", str(path), "--recalibration-s", "1e308"]) == 2
    assert "recalibration_s=1e+308" in capsys.readouterr().err


_POSES2 = {"S1": [0.0, 0.0, 0.0], "S2": [0.0, 7.0, np.pi]}


@pytest.mark.parametrize("option", ["frame_period_s", "threshold", "recalibration_s",
                                    "windows_s", "node_covariances"])
@pytest.mark.parametrize("value", [[0.15], [1.0, 2.0], "0.15", None, True, {}, (0.5,), "x",
                                   10 ** 400, np.array([0.1, 0.2])])
def test_odd_option_values_are_validation_errors(option, value):
    """Before: list- and string-valued options raised plain ValueError or
    TypeError ("truth value of an array is ambiguous", "'>' not supported")."""
    if option == "windows_s" and isinstance(value, (list, tuple, np.ndarray)) \
            and not isinstance(value, str):
        DecalibrationMonitor(_POSES2, windows_s=value)  # a list of lengths is right here
        return
    if option == "node_covariances" and (value is None or (isinstance(value, dict) and not value)):
        DecalibrationMonitor(_POSES2, node_covariances=value)  # none given: the defaults
        return
    with pytest.raises(ValidationError, match=option) as info:
        DecalibrationMonitor(_POSES2, **{option: value})
    assert "np.float64" not in str(info.value) and "array(" not in str(info.value)


@pytest.mark.parametrize("row", [[3.5, 0.1], [3.5, 0.1, 0.2, 4.0], [[3.5, 0.1, 0.2]], "abc", {}])
def test_a_short_or_long_row_is_a_validation_error(row):
    """Before: {'S1': [3.5, 0.1]} raised ValueError "could not broadcast"."""
    monitor = DecalibrationMonitor(_POSES2)
    with pytest.raises(ValidationError, match=r"measurements\['S1'\]"):
        monitor.update({"S1": row, "S2": [4.0, 0.1, 0.2]})
