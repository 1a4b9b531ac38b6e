"""`mmsnap info` and :func:`recording_info`: what a recording holds, read
without loading it, checked against h5py reads of the same file."""

from __future__ import annotations

import json

import h5py
import numpy as np
import pytest

from mmsnap_graph.app.cli import main
from mmsnap_graph.app.recording_info import format_info, recording_info


@pytest.fixture(scope="module")
def fused_file(tmp_path_factory):
    """Configuration B, 120 frames of centroids: simulated, calibrated, fused."""
    path = tmp_path_factory.mktemp("info") / "rec.h5"
    assert main(["simulate", "-c", "B", "-t", "random", "-l", "centroids", "--model", "clean", "-n", "120",
                 "--seed", "2", "-o", str(path)]) == 0
    assert main(["calibrate", str(path)]) == 0
    assert main(["fuse", str(path)]) == 0
    return path


def test_info_counts_match_the_file(fused_file):
    info = recording_info(fused_file)
    with h5py.File(fused_file, "r") as f:
        assert info["frame_period_s"] == pytest.approx(float(f.attrs["frame_period_s"]))
        for name in ("S1", "S2"):
            frames = f[f"nodes/{name}/centroids/frame"][()]
            level = info["nodes"][name]["levels"]["centroids"]
            assert level["rows"] == frames.size
            assert level["frames"] == np.unique(frames).size
            assert (level["first_frame"], level["last_frame"]) == (frames.min(), frames.max())
        success = f["fused/success"][()]
        assert info["fused"]["rows"] == success.size
        assert info["fused"]["succeeded"] == int(success.sum())
        assert sum(info["fused"]["status_counts"].values()) == success.size
        pose = f["calibration/pose"][1]
    assert info["calibration"]["nodes"]["S2"]["pose"] == pytest.approx(pose.tolist())
    assert info["truth"] is True
    assert info["frames"]["duration_s"] == pytest.approx(120 * info["frame_period_s"])


def test_info_text_has_units_and_degrees(fused_file):
    text = format_info(recording_info(fused_file))
    phi = recording_info(fused_file)["calibration"]["nodes"]["S2"]["pose"][2]
    assert f"phi {np.degrees(phi):+.2f} deg" in text
    assert "frame period 150.00 ms" in text
    assert "status 0 converged" in text


def test_info_on_a_recording_without_results_says_what_to_run(tmp_path, capsys):
    path = tmp_path / "bare.h5"
    assert main(["simulate", "-c", "A", "-t", "straight", "-l", "centroids", "--model", "clean", "-n", "20",
                 "-o", str(path)]) == 0
    capsys.readouterr()
    assert main(["info", str(path)]) == 0
    out = capsys.readouterr().out
    assert "run `mmsnap calibrate FILE`" in out and "run `mmsnap fuse FILE`" in out


def test_info_json_is_read_only_and_parses(fused_file, capsys):
    before = fused_file.read_bytes()
    capsys.readouterr()
    assert main(["info", str(fused_file), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert set(data["nodes"]) == {"S1", "S2"}
    assert fused_file.read_bytes() == before


@pytest.mark.parametrize("content", [None, b"not an hdf5 file"])
def test_info_on_a_missing_or_bad_file_is_one_line_exit_1(tmp_path, capsys, content):
    path = tmp_path / "x.h5"
    if content is not None:
        path.write_bytes(content)
    assert main(["info", str(path)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(path) in err[0]
