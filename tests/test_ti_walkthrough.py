"""docs/TI.md's walkthrough with the samples in data/ti runs as written, with
CLI commands only (issue 14, "Done when"): every ``mmsnap`` command of its
blocks exits 0, in a scratch directory holding a copy of ``data/ti``, and the
calibrated and fused recordings are what the page says. Before, the point
cloud samples were 20 frames (``mmsnap calibrate`` found no pair of tracks
sharing 10 frames), only S1 had a UART log, and the raw capture's slow target
sat in the zero-Doppler bin that clutter removal empties (0 points)."""

from __future__ import annotations

import re
import shlex
import shutil
from pathlib import Path

import numpy as np
import pytest

from mmsnap_graph.app.cli import main
from mmsnap_graph.io import read_fused, read_recording

from _shared import ROOT, TI_DATA
from ti_samples import FAST_TARGET, write_fast_sample

TI_MD = ROOT / "docs" / "TI.md"
#: S2's true pose in the samples (tests/ti_samples.py: configuration C).
S2_POSE = np.array([0.0, 7.0, np.pi])


def walkthrough_blocks() -> list[list[list[str]]]:
    """The ``mmsnap`` commands of each fenced block of the walkthrough section."""
    text = TI_MD.read_text()
    section = text.split("## Walkthrough with the samples", 1)[1].split("\n## ", 1)[0]
    blocks = []
    for body in re.findall(r"```bash\n(.*?)```", section, flags=re.S):
        joined = body.replace("\\\n", " ")
        commands = [shlex.split(line)[1:] for line in joined.splitlines()
                    if line.startswith("mmsnap ")]
        blocks.append(commands)
    return blocks


BLOCKS = walkthrough_blocks()


def test_the_walkthrough_has_every_kind_of_sample():
    firsts = [block[0][:2] for block in BLOCKS]
    assert ["import", "table"] in firsts and ["import", "ti-uart"] in firsts
    assert ["import", "dca1000"] in firsts
    outputs = [block[0][block[0].index("-o") + 1] for block in BLOCKS]
    assert "fast.h5" in outputs                           # the target beyond +-v_max
    verbs = [cmd[0] for block in BLOCKS for cmd in block]
    assert {"process", "calibrate", "fuse"} <= set(verbs)


@pytest.fixture()
def scratch(tmp_path, monkeypatch):
    shutil.copytree(TI_DATA, tmp_path / "data" / "ti")
    monkeypatch.chdir(tmp_path)
    return tmp_path


@pytest.mark.parametrize("block", BLOCKS, ids=lambda b: " ".join(b[0][:2]))
def test_walkthrough_block_runs_and_gives_what_the_page_says(block, scratch, capsys):
    printed = ""
    for argv in block:
        code = main(argv)
        captured = capsys.readouterr()
        assert code == 0, (argv, captured.err)
        printed += captured.out
    out = Path(block[0][block[0].index("-o") + 1])
    if any(argv[0] == "calibrate" for argv in block):   # the pose the page quotes
        quoted = re.search(r"`mmsnap calibrate` prints S2's pose: \(([-0-9.]+), ([-0-9.]+)\) "
                           r"m, ([-0-9.]+) degrees", TI_MD.read_text())
        row = next(line.split() for line in printed.splitlines() if line.startswith("S2 "))
        assert row[1:4] == list(quoted.groups()), (row, quoted.groups())
    rec = read_recording(out)
    if out.name == "raw.h5":                # three frames of one node: a point cloud
        assert len(rec.nodes["S1"].point_cloud) == 8
        assert len(rec.nodes["S1"].centroids) == 2
        return
    if out.name == "fast.h5":
        _assert_fast_target(rec.nodes["S1"].point_cloud, dealiased=True)
        return
    pose = rec.nodes["S2"].pose
    # "within 1 cm and 0.1 degree of the truth"
    assert np.hypot(*(pose[:2] - S2_POSE[:2])) < 0.01
    assert abs(np.angle(np.exp(1j * (pose[2] - S2_POSE[2])))) < np.deg2rad(0.1)
    fused = read_fused(out)
    assert len(np.unique(fused.frame)) == 100 and np.all(np.isfinite(fused.state))


def _assert_fast_target(cloud, *, dealiased: bool):
    """"-8.49 m/s and 0.927 rad (true 0.928)"; aliased "+4.33 m/s" and the
    angle "off by 0.40 rad"."""
    _, azimuth, speed = FAST_TARGET
    assert cloud.frame.tolist() == [0, 1, 2]
    omega = np.pi * np.sin(azimuth)
    if dealiased:
        np.testing.assert_allclose(cloud.doppler_mps, speed, atol=0.02)
        np.testing.assert_allclose(cloud.omega_rad, omega, atol=0.005)
    else:
        np.testing.assert_allclose(cloud.doppler_mps, 4.33, atol=0.02)
        np.testing.assert_allclose(omega - cloud.omega_rad, 0.40, atol=0.01)


def test_the_fast_target_stays_aliased_without_dealiasing(scratch):
    """The doc's comparison: the same capture processed with doppler_wraps = 0."""
    (scratch / "nowrap.toml").write_text("[chain]\ndoppler_wraps = 0\n")
    assert main(["import", "dca1000", "--cfg", "data/ti/dca1000_fast.cfg", "--board",
                 "AWR1843BOOST", "--node", "S1=data/ti/dca1000_fast.bin", "-o", "f.h5"]) == 0
    assert main(["process", "f.h5", "--config", "nowrap.toml"]) == 0
    _assert_fast_target(read_recording("f.h5").nodes["S1"].point_cloud, dealiased=False)


def test_the_fast_sample_is_what_the_script_makes(tmp_path):
    write_fast_sample(tmp_path)
    for name in ("dca1000_fast.cfg", "dca1000_fast.bin"):
        assert (tmp_path / name).read_bytes() == (TI_DATA / name).read_bytes(), name


def test_the_stone_soup_block_runs_and_prints_what_the_page_says(scratch, capsys):
    """The page's Stone Soup tracker (after ``pip install ".[stonesoup]"``)
    on the CSV walkthrough's ``table.h5``."""
    pytest.importorskip("stonesoup")
    text = TI_MD.read_text()
    section = text.split("## Handing the fused states to a tracker (Stone Soup)", 1)[1]
    section = section.split("\n## ", 1)[0]
    assert 'pip install ".[stonesoup]"' in section
    (code,) = re.findall(r"```python\n(.*?)```", section, flags=re.S)
    for argv in BLOCKS[0]:
        assert main(argv) == 0
    capsys.readouterr()
    exec(compile(code, "TI.md", "exec"), {"__name__": "__main__"})
    out = capsys.readouterr().out
    n, x, y = re.search(r"It prints (\d+) track states \(the last at x ([-0-9.]+) m, "
                        r"y ([-0-9.]+) m\)", section).groups()
    one_shot, tracked = re.search(r"median x\s+sigma of ([0-9.]+) cm one-shot against "
                                  r"([0-9.]+) cm tracked", section).groups()
    assert f"{n} track states; last: x {x} m, y {y} m" in out, out
    assert f"x sigma: one-shot {one_shot} cm, tracked {tracked} cm" in out, out
