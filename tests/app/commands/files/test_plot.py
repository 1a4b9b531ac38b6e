"""``mmsnap plot`` (mmsnap_graph.app.commands.files.plot) on a simulated,
calibrated and fused recording (tests/app/conftest.py's ``fused_b_file``)."""

from __future__ import annotations

from mmsnap_graph.app.cli import main


def test_the_command_writes_png_and_svg_and_refuses_other_formats(fused_b_file, tmp_path,
                                                                  capsys):
    png, svg = tmp_path / "walk.png", tmp_path / "walk.svg"
    assert main(["plot", str(fused_b_file), "-o", str(png), "--dpi", "120",
                 "--frames", "10,60"]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    from matplotlib.image import imread
    height, width = imread(png).shape[:2]
    assert width >= 9 * 120 * 0.8 and height >= 6 * 120 * 0.8   # 9 x 7.5 in, tight box
    assert main(["plot", str(fused_b_file), "-o", str(svg)]) == 0
    assert b"<svg" in svg.read_bytes()[:400]
    assert main(["plot", str(fused_b_file), "-o", str(svg)]) == 2
    assert "pass --overwrite" in capsys.readouterr().err
    assert main(["plot", str(fused_b_file), "-o", str(tmp_path / "walk.pdf")]) == 2
    assert "written as png or svg" in capsys.readouterr().err
    assert main(["plot", str(fused_b_file), "-o", str(png), "--overwrite", "--dpi", "72"]) == 2
    assert "dpi=72 must be an integer within [100, 600] (--dpi)" in capsys.readouterr().err
    assert main(["plot", str(fused_b_file), "-o", str(png), "--overwrite",
                 "--frames", "9,3"]) == 2
