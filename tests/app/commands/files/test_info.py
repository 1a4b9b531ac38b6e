"""``mmsnap info`` (mmsnap_graph/app/commands/files/info.py): read only, one-line errors."""

from __future__ import annotations

import json

import pytest

from mmsnap_graph.app.cli import main


def test_info_on_a_recording_without_results_says_what_to_run(tmp_path, capsys):
    path = tmp_path / "bare.h5"
    assert main(["simulate", "-c", "A", "-t", "straight", "-l", "centroids", "--model", "clean", "-n", "20",
                 "-o", str(path)]) == 0
    capsys.readouterr()
    assert main(["info", str(path)]) == 0
    out = capsys.readouterr().out
    assert "run `mmsnap calibrate FILE`" in out and "run `mmsnap fuse FILE`" in out


def test_info_json_is_read_only_and_parses(fused_b_file, capsys):
    before = fused_b_file.read_bytes()
    capsys.readouterr()
    assert main(["info", str(fused_b_file), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert set(data["nodes"]) == {"S1", "S2"}
    assert fused_b_file.read_bytes() == before


@pytest.mark.parametrize("content", [None, b"not an hdf5 file"])
def test_info_on_a_missing_or_bad_file_is_one_line_exit_1(tmp_path, capsys, content):
    path = tmp_path / "x.h5"
    if content is not None:
        path.write_bytes(content)
    assert main(["info", str(path)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(path) in err[0]
