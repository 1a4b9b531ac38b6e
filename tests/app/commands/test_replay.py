"""mmsnap replay: odd --speed values are usage errors, and a reader that
closes the pipe (``| head``) ends the run quietly."""

from __future__ import annotations

import shutil
import subprocess
import sys

import pytest

from mmsnap_graph.app.cli import EXIT_BROKEN_PIPE, main
from _cli import noise_block, store_partial_noise


@pytest.fixture(scope="module")
def rec(tmp_path_factory):
    path = tmp_path_factory.mktemp("replay") / "rec.h5"
    assert main(["simulate", "-c", "B", "-t", "random", "-n", "400", "-l", "centroids",
                 "--seed", "2", "--known-poses", "-o", str(path), "--no-progress"]) == 0
    return path


@pytest.mark.parametrize("speed", ["1e-20", "0", "-1", "nan", "inf", "1e300"])
def test_a_speed_out_of_range_is_a_usage_error(rec, capsys, speed):
    assert main(["replay", str(rec), "--summary", "--speed", speed]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--speed must be between" in err


def test_a_closed_pipe_ends_the_replay_quietly(rec):
    proc = subprocess.Popen([sys.executable, "-m", "mmsnap_graph", "replay", str(rec)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    assert proc.stdout.readline().startswith(b"frame")
    proc.stdout.close()  # as `head -1` does
    assert proc.wait(timeout=60) == EXIT_BROKEN_PIPE
    err = proc.stderr.read().decode()
    assert "error" not in err and "Broken pipe" not in err and "Traceback" not in err, err


def test_replay_prints_the_stored_noise_one_short_line_per_node(recording_b_file, tmp_path,
                                                                capsys):
    path = shutil.copy(recording_b_file, tmp_path / "rec.h5")
    store_partial_noise(path)
    assert main(["replay", str(path), "--summary"]) == 0
    noise_block(capsys.readouterr().err)  # the frames go to stdout


def test_view_log_holds_each_frames_people_as_the_replay_prints_them(recording_b_file,
                                                                     tmp_path, capsys):
    """``--view-log``: the MCAP's /persons rows are the tracks of the replay's
    JSON lines, frame for frame (read back with the mcap reader)."""
    import json

    pytest.importorskip("foxglove")
    from mcap.reader import make_reader

    out, log = tmp_path / "replay.jsonl", tmp_path / "replay.mcap"
    assert main(["replay", str(recording_b_file), "--summary", "-o", str(out),
                 "--view-log", str(log)]) == 0
    assert f"wrote {log} (open it in Foxglove or Lichtblick)" in capsys.readouterr().out
    want = {}
    for line in out.read_text().splitlines():
        r = json.loads(line)
        want[r["frame"]] = [(tid, x) for tid, x in zip(r["track_id"], r["track_state"])]
    got = {}
    with open(log, "rb") as f:
        for _, channel, message in make_reader(f).iter_messages(topics=["/persons"]):
            m = json.loads(message.data)
            got[m["frame"]] = [(p["id"], [p["x_m"], p["y_m"], p["vx_mps"], p["vy_mps"]])
                               for p in m["people"]]
    assert got == want and any(got.values())


def _mean_sigmas(path):
    import numpy as np

    from mmsnap_graph.io.noise import read_noise

    return np.mean([n.sigmas for n in read_noise(path).per_node.values()], axis=0)


def test_replay_says_the_covariance_self_check_and_warns_loudly_when_it_fails(
        calibrated_c_file, capsys):
    """The self-check of `mmsnap fuse` over the streamed rows: a JSON line on
    stderr when the verdict changes and the final line; the loud sentence
    only when the sigmas (0.3x the data's) make the covariances wrong;
    nothing of it with --no-self-check."""
    import json

    capsys.readouterr()
    assert main(["replay", str(calibrated_c_file), "--summary"]) == 0
    err = capsys.readouterr().err
    verdicts = [json.loads(line)["self_check"]["verdict"] for line in err.splitlines()
                if line.startswith('{"type": "self_check"')]
    assert verdicts == ["consistent"], err
    assert "covariance self-check (no truth): consistent" in err and "warning" not in err
    low = [f"{v:.5g}" for v in 0.3 * _mean_sigmas(calibrated_c_file)]
    assert main(["replay", str(calibrated_c_file), "--summary", "--sigmas", *low]) == 0
    err = capsys.readouterr().err
    assert "mmsnap replay: warning: the fused covariances are over-confident" in err
    assert '"verdict": "over-confident"' in err
    assert main(["replay", str(calibrated_c_file), "--summary", "--sigmas", *low,
                 "--no-self-check"]) == 0
    err = capsys.readouterr().err
    assert "self-check" not in err and "self_check" not in err and "warning" not in err
