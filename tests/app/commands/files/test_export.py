"""``mmsnap export`` (mmsnap_graph/app/commands/files/export.py): what it refuses and why."""

from __future__ import annotations

from mmsnap_graph.app.cli import main


def test_export_before_fuse_names_the_command(tmp_path, capsys):
    path = tmp_path / "bare.h5"
    assert main(["simulate", "-c", "A", "-t", "straight", "-l", "centroids", "--model", "clean", "-n", "20",
                 "-o", str(path)]) == 0
    capsys.readouterr()
    assert main(["export", str(path), "fused"]) == 1
    assert f"run `mmsnap fuse {path}` first" in capsys.readouterr().err


def test_export_refuses_to_replace_a_file_without_overwrite(fused_b_file, tmp_path, capsys):
    out = tmp_path / "t.csv"
    out.write_text("keep me")
    assert main(["export", str(fused_b_file), "calibration", "-o", str(out)]) == 2
    assert out.read_text() == "keep me"
    assert main(["export", str(fused_b_file), "calibration", "-o", str(out), "--overwrite"]) == 0
    assert out.read_text().startswith("node,")
