"""``mmsnap fuse``: the /fused group it writes and reads back, the calibration it takes, its errors (the library side: tests/fusion/recording/test_sequence.py)."""

import json
import dataclasses
import shutil

import numpy as np
import pytest

from mmsnap_graph.data.noise import MeasurementNoise
from mmsnap_graph.data.results import Status
from mmsnap_graph.app.cli import main
from mmsnap_graph.errors import CalibrationError
from mmsnap_graph.io import read_recording, write_recording
from mmsnap_graph.fusion.options import NetworkCalibration
from mmsnap_graph.fusion.recording.sequence import (
    fuse_recording,
    recording_poses,
    group_detections,
)
from mmsnap_graph.io.calibration import load_calibration_poses
from mmsnap_graph.io.fused import read_fused
from _cli import noise_block, store_partial_noise, with_centroids
from _fusion import config


@pytest.fixture
def recordings(two_target_recordings):
    """Two walking targets, 10 % missed centroids, per configuration (conftest)."""
    return two_target_recordings


def test_calibration_json_and_pose_sources(tmp_path, recordings):
    rec = recordings["C"]
    calib = {"reference": "S1", "nodes": {"S1": {"pose": [0, 0, 0], "covariance": np.eye(3).tolist()},
                                          "S2": {"pose": [0.1, 6.9, np.pi - 0.02]}}}
    path = tmp_path / "calib.json"
    path.write_text(json.dumps(calib))
    poses = load_calibration_poses(path)
    np.testing.assert_array_equal(recording_poses(rec, poses)[1], [0.1, 6.9, np.pi - 0.02])
    np.testing.assert_array_equal(recording_poses(rec), np.stack([rec.nodes[n].pose for n in rec.node_names]))
    fused = fuse_recording(rec, config(), calibration=NetworkCalibration(node_poses=poses))
    np.testing.assert_array_equal(fused.node_poses[1], [0.1, 6.9, np.pi - 0.02])


def test_missing_calibration_file_and_poses(tmp_path, recordings):
    with pytest.raises(CalibrationError, match="does not exist"):
        load_calibration_poses(tmp_path / "none.json")
    rec = recordings["A"]
    with pytest.raises(CalibrationError, match="no pose for node 'S2'"):
        recording_poses(rec, {"S1": [0, 0, 0]})
    import dataclasses

    bare = rec.with_node(dataclasses.replace(rec.nodes["S2"], pose=None))
    with pytest.raises(CalibrationError, match="node 'S2' has no pose in the recording"):
        fuse_recording(bare, config())


def test_cli_fuse_writes_the_fused_group(tmp_path, recordings, capsys):
    rec = recordings["B"]
    path = write_recording(tmp_path / "rec.h5", rec)
    calib = tmp_path / "calib.json"
    calib.write_text(json.dumps({"nodes": {n: {"pose": rec.nodes[n].pose.tolist()} for n in rec.node_names}}))
    assert main(["fuse", str(path), "--calibration", str(calib), "--mode", "ml", "--no-progress"]) == 0
    assert "wrote" in capsys.readouterr().out
    fused = read_fused(path)
    assert fused.mode == "ml" and fused.covariance_method == "laplace" and fused.solver == "vectorized"
    from mmsnap_graph.fusion.recording.room import DEFAULT_BODY_M, screen_room
    # The CLI's default: the robust gate, then one target per body.
    ref = screen_room(fuse_recording(rec, config(mode="ml", robust="gate")), body_m=DEFAULT_BODY_M)[0]
    np.testing.assert_allclose(fused.state[fused.success], ref.state[ref.success], atol=1e-12)
    out = tmp_path / "copy.h5"
    assert main(["fuse", str(path), "-o", str(out), "--no-progress"]) == 0
    assert read_fused(out).mode == "map" and read_fused(path).mode == "ml"
    assert main(["fuse", str(path), "--calibration", str(tmp_path / "none.json")]) == 1
    assert "does not exist" in capsys.readouterr().err


def test_cli_fuse_takes_measurement_sigmas(tmp_path, recordings, capsys):
    rec = recordings["B"]
    path = write_recording(tmp_path / "rec.h5", rec)
    assert main(["fuse", str(path), "--sigmas", "0.05", "0.08", "0.1", "--no-progress"]) == 0
    fused = read_fused(path)
    np.testing.assert_allclose(fused.noise_sigmas, [0.05, 0.08, 0.1])
    ref = fuse_recording(rec, config(), noise=MeasurementNoise(range_m=0.05, omega_rad=0.08,
                                                             doppler_mps=0.1))
    np.testing.assert_allclose(fused.covariance[fused.success], ref.covariance[ref.success],
                               atol=1e-12)
    assert main(["fuse", str(path), "--sigmas", "0.05", "-1", "0.1", "--no-progress"]) == 2
    assert "omega_rad must be finite and > 0" in capsys.readouterr().err




def test_a_run_flagging_most_rows_exits_1_and_says_why(recording_b_real_file, tmp_path, capsys):
    # Sigmas far below the data's noise: most rows fuse into flags (room
    # checks aside), which was exit 0 whatever the share.
    from mmsnap_graph.app.cli import main

    rec = shutil.copy(recording_b_real_file, tmp_path / "rec.h5")
    tiny = ["--sigmas", "0.001", "0.001", "0.001", "--no-progress"]
    capsys.readouterr()
    code = main(["fuse", str(rec), *tiny, "--max-flagged", "0.5"])  # 80 % flagged here
    err = capsys.readouterr().err
    assert code == 1, err
    assert "fused rows" in err and "more than --max-flagged 0.5" in err
    assert main(["fuse", str(rec), *tiny, "--max-flagged", "1"]) == 0
    # The default allows up to 90 % (without the placement check: with it, the
    # one-node rows the gate leaves of every row are flagged too, and it exits 1).
    assert main(["fuse", str(rec), *tiny, "--no-placement-check"]) == 0
    assert main(["fuse", str(rec), "--no-progress"]) == 0  # a clean run flags fewer


@pytest.mark.parametrize("sigmas,name", [(["0.05", "5", "0.1"], "omega_rad=5 is more than"),
                                         (["35", "0.1", "0.1"], "range_m=35 is more than"),
                                         (["0.05", "0.1", "0"], "doppler_mps must be")])
@pytest.mark.parametrize("verb", ["fuse", "monitor", "calibrate"])
def test_implausible_sigmas_name_the_flag_and_the_unit(capsys, verb, sigmas, name):
    from mmsnap_graph.app.cli import main

    assert main([verb, "rec.h5", "--sigmas", *sigmas]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"--sigmas: {name}" in err


def test_group_detections_and_fuse_go_on_past_degenerate_centroids(recording_b_file, tmp_path,
                                                                  capsys):
    rec = read_recording(recording_b_file)

    def edit(r, w, v):
        r[[3, 5, 7]] = [0.0, 0.0, 1e-300]
        w[[3, 5]] = [0.0, np.pi]

    bad = with_centroids(rec, 0, edit)
    poses = np.array([bad.nodes[n].pose for n in bad.node_names])
    groups = group_detections(bad, poses)
    assert np.unique(groups.frame).size == np.unique(np.concatenate(
        [bad.nodes[n].centroids.frame for n in bad.node_names])).size
    path = write_recording(tmp_path / "bad.h5", bad)
    assert main(["fuse", str(path), "--no-progress"]) == 0
    assert "flagged" in capsys.readouterr().out
    assert main(["fuse", str(recording_b_file), "--no-progress", "-o", str(tmp_path / "s.h5"),
                 "--sigmas", "1e-55", "1e-55", "1e-55", "--max-flagged", "1"]) == 0
    capsys.readouterr()
    assert main(["fuse", str(recording_b_file), "--no-progress", "-o", str(tmp_path / "t.h5"),
                 "--sigmas", "1e-300", "1e-300", "1e-300"]) == 2
    err = capsys.readouterr().err.strip()
    assert "sigmas" in err and len(err.splitlines()) == 1


def test_grid_points_below_five_are_a_usage_error(recording_b_file, capsys):
    assert main(["fuse", str(recording_b_file), "--covariance", "grid", "--grid-points", "4"]) == 2
    assert "--grid-points" in capsys.readouterr().err




def test_fuse_says_what_its_row_counts_mean(tmp_path, capsys):
    """"fused 614 targets in 600 frames" from one walker: the output says a
    row is a (frame, target) of the association, how many rows all nodes saw,
    how many frames hold several targets and why, and the flagged statuses."""
    import numpy as np

    from mmsnap_graph.app.cli import main
    from mmsnap_graph.data.results import Status
    from mmsnap_graph.io import read_fused

    path = tmp_path / "rec.h5"
    assert main(["simulate", "-c", "C", "-t", "random", "-n", "300", "--seed", "1", "-l",
                 "centroids", "--known-poses", "-o", str(path), "--no-progress"]) == 0
    capsys.readouterr()
    assert main(["fuse", str(path), "--no-progress"]) == 0
    out = capsys.readouterr().out
    fused = read_fused(path)
    seen = fused.observed.sum(axis=1)
    _, per_frame = np.unique(fused.frame, return_counts=True)
    assert (f"rows: one per (frame, target) of the association; {np.sum(seen == 2)} seen by "
            f"all 2 nodes, {np.sum(seen < 2)} by fewer") in out
    assert f"  {np.sum(per_frame > 1)} frames hold more than one target: " in out
    codes, counts = np.unique(fused.status[fused.status != 0], return_counts=True)
    for c, n in zip(codes, counts):
        assert f"{n} {Status(int(c)).name.lower()} ({int(c)})" in out


def test_cli_fuse_merges_one_body_and_checks_coverage_unless_told(tmp_path):
    """``mmsnap fuse`` merges a node's centroids of one body and runs the
    coverage check; ``--no-body-merge`` and ``--no-coverage-check`` give the
    library's rows without them."""
    from _shared import POSES_BC
    from mmsnap_graph.fusion.options import FusionOptions
    from mmsnap_graph.fusion.recording.room import DEFAULT_BODY_M, screen_room
    from mmsnap_graph.sim import SimulationOptions, simulate_recording
    from mmsnap_graph.sim.real.ghosts import ghost_centroids
    from mmsnap_graph.sim.simulator import CENTROID_NOISE

    net = {"S1": POSES_BC[0], "S2": POSES_BC[1], "S3": POSES_BC[2]}
    rec = simulate_recording(net, "random", SimulationOptions(physics=None, known_poses=True),
                             levels=("centroids",), n_frames=120, seed=2)
    rec = ghost_centroids(ghost_centroids(rec, "split", 0.2, seed=3), "mirror", 0.2, seed=4)
    path = write_recording(tmp_path / "rec.h5", rec)
    # The placement check (not in the library config of tests/_fusion.py) left out.
    sig = ["--sigmas", "0.05", "0.08", "0.1", "--no-progress", "--no-placement-check"]
    for flags, opts in (([], {}),
                        (["--no-body-merge", "--no-coverage-check"],
                         dict(body_merge=False, coverage_check=False))):
        assert main(["fuse", str(path), *sig, *flags, "--overwrite"]) == 0
        fused = read_fused(path)
        ref = fuse_recording(rec, config(robust="gate", walls=True, body_m=DEFAULT_BODY_M, **opts),
                             noise=CENTROID_NOISE, progress=False)
        np.testing.assert_array_equal(fused.frame, ref.frame)
        np.testing.assert_array_equal(fused.status, ref.status)
    # The split halves are rows of their own without the merge.
    assert len(fuse_recording(rec, config(robust="gate"), noise=CENTROID_NOISE, progress=False)) < len(ref)


# ``mmsnap fuse`` takes the calibration's pose covariances and clock offsets by
# default, and options turn them off.


@pytest.fixture()
def calibrated(calibrated_c_file, tmp_path):
    """A copy of the shared calibrated recording and its calibration JSON
    (fuse writes into the recording)."""
    for name in ("rec.h5", "rec.calibration.json"):
        shutil.copy(calibrated_c_file.with_name(name), tmp_path / name)
    return tmp_path / "rec.h5"


def test_default_fuse_includes_the_pose_covariances_and_offsets(calibrated, capsys):
    capsys.readouterr()
    assert main(["fuse", str(calibrated), "--no-progress"]) == 0
    text = capsys.readouterr().out
    assert "pose covariances of S2 included" in text and "clock offsets applied: S2" in text
    with_poses = read_fused(calibrated)
    assert main(["fuse", str(calibrated), "--no-progress", "--no-pose-covariance"]) == 0
    assert "poses exact" in capsys.readouterr().out
    exact = read_fused(calibrated)
    # Same estimates; the calibration's uncertainty only widens the covariance.
    np.testing.assert_array_equal(exact.state, with_poses.state)
    ok = exact.success & with_poses.success
    grow = np.linalg.eigvalsh(with_poses.covariance[ok] - exact.covariance[ok])
    assert np.all(grow > -1e-12) and np.median(grow[:, -1]) > 0
    assert main(["fuse", str(calibrated), "--no-progress", "--no-time-offsets"]) == 0
    assert "clocks as recorded" in capsys.readouterr().out
    assert not np.array_equal(read_fused(calibrated).state, with_poses.state)


def test_a_calibration_json_gives_poses_and_covariances(calibrated, capsys):
    json_path = calibrated.with_name("rec.calibration.json")
    assert json_path.exists()
    capsys.readouterr()
    out = calibrated.with_name("copy.h5")
    assert main(["fuse", str(calibrated), "--calibration", str(json_path), "--no-progress",
                 "--no-time-offsets", "-o", str(out)]) == 0
    assert "pose covariances of S2 included" in capsys.readouterr().out
    assert main(["fuse", str(calibrated), "--covariance", "grid", "--grid-points", "5",
                 "--no-progress", "-o", str(out), "--overwrite"]) == 0
    assert "pose covariances need --covariance laplace" in capsys.readouterr().out


def test_fuse_prints_the_stored_noise_one_short_line_per_node(recording_b_file, tmp_path, capsys):
    path = shutil.copy(recording_b_file, tmp_path / "rec.h5")
    store_partial_noise(path)
    assert main(["fuse", str(path), "--no-progress"]) == 0
    noise_block(capsys.readouterr().out)


def test_fuse_without_a_config_file_imports_no_signal_chain(recording_b_file, tmp_path):
    """Before: the fusion flags read through the TOML module, which imports
    the signal chain's configurations (scikit-learn, pandas): 60 MB more
    peak memory for every `mmsnap fuse` (benchmarks/bench_fuse_memory.py
    --paths cli: 184 -> 245 MB)."""
    import subprocess
    import sys

    code = ("import io, sys, contextlib\n"
            "from mmsnap_graph.app.cli import main\n"
            "with contextlib.redirect_stdout(io.StringIO()):\n"
            f"    code = main(['fuse', {str(recording_b_file)!r}, '-o', "
            f"{str(tmp_path / 'f.h5')!r}, '--no-progress', '--max-flagged', '1'])\n"
            "print(code, 'sklearn' in sys.modules, 'mmsnap_graph.radar.chain' in sys.modules)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.split()
    assert out == ["0", "False", "False"], out


def test_fuse_reports_the_covariance_self_check_and_warns_when_it_fails(calibrated, capsys):
    """The self-check without truth (fusion.recording.consistency): in the
    text, in --json, stored on /fused; loud on stderr when sigmas 0.3x the
    data's make the covariances too small."""
    import h5py

    from mmsnap_graph.io.noise import read_noise

    capsys.readouterr()
    assert main(["fuse", str(calibrated), "--no-progress", "--json"]) == 0
    cap = capsys.readouterr()
    good = json.loads(cap.out)["consistency"]
    assert good["verdict"] == "consistent", good
    assert "covariance self-check (no truth): consistent" in cap.err
    assert "warning" not in cap.err
    with h5py.File(calibrated, "r") as f:
        assert json.loads(f["fused"].attrs["consistency"]) == good
    sig = np.mean([n.sigmas for n in read_noise(calibrated).per_node.values()], axis=0)
    out = calibrated.with_name("low.h5")
    assert main(["fuse", str(calibrated), "--no-progress", "--json", "-o", str(out),
                 "--sigmas", *(f"{v:.6g}" for v in 0.3 * sig), "--max-flagged", "1"]) == 0
    cap = capsys.readouterr()
    bad = json.loads(cap.out)["consistency"]
    assert bad["verdict"] == "over-confident" and bad["consistent"] is False
    assert "mmsnap fuse: warning: the fused covariances are over-confident" in cap.err
