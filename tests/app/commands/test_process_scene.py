"""``mmsnap process`` on a real TI point cloud: the scene filters report what
they dropped, and each switch turns its filter off."""

from __future__ import annotations

import csv

import pytest

from _shared import DATA
from mmsnap_graph.app.cli import main
from mmsnap_graph.io import read_recording

REAL = DATA / "real" / "darksz"


@pytest.fixture(scope="module")
def imported(tmp_path_factory):
    """The first 10 s of the two-person recording, imported as docs/TI.md says."""
    d = tmp_path_factory.mktemp("scene")
    tables = []
    for node in ("S1", "S2"):
        with open(REAL / f"multiple_tracking_{node}.csv", newline="") as f:
            rows = list(csv.reader(f))
        k = rows[0].index("frame")
        path = d / f"{node}.csv"
        with open(path, "w", newline="") as f:
            csv.writer(f).writerows([rows[0]] + [r for r in rows[1:] if int(r[k]) < 200])
        tables.append(path)
    out = d / "mt.h5"
    assert main(["import", "table", "--node", f"S1={tables[0]}", "--node", f"S2={tables[1]}",
                 "--frame-period", "0.05", "--mount", "S1=0.8,0", "--mount", "S2=1.1,0",
                 "--room-pose", "S1=0,0,0", "--room-pose", "S2=1.7,1.65,90",
                 "--height-band", "0.2,2.0", "-o", str(out)]) == 0
    return out


def _process(src, tmp_path, *flags):
    out = tmp_path / "p.h5"
    assert main(["process", str(src), "-o", str(out), "--no-progress", *flags]) == 0
    return read_recording(out)


def test_scene_filters_are_on_and_say_what_they_dropped(imported, tmp_path, capsys):
    on = _process(imported, tmp_path)
    text = capsys.readouterr().out
    assert "static-scene points" in text and "multipath ghosts" in text
    assert "centroids merged (one body)" in text and "centroids without existence" in text
    off = _process(imported, tmp_path, "--no-static-scene", "--no-body-merge",
                   "--no-ghost-filter", "--no-existence-check")
    assert "dropped" not in capsys.readouterr().out
    # The stored point cloud is kept whole; the centroids are fewer.
    assert len(on.nodes["S2"].point_cloud) == len(off.nodes["S2"].point_cloud)
    assert len(on.nodes["S2"].centroids) < len(off.nodes["S2"].centroids)


@pytest.mark.parametrize("flag, word", [("--no-static-scene", "static-scene points"),
                                        ("--no-body-merge", "merged (one body)"),
                                        ("--no-ghost-filter", "multipath ghosts"),
                                        ("--no-existence-check", "without existence")])
def test_each_switch_turns_one_filter_off(imported, tmp_path, capsys, flag, word):
    _process(imported, tmp_path, flag)
    text = capsys.readouterr().out
    assert word not in text and "dropped" in text
