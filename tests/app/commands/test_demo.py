"""``mmsnap demo``: its arguments, its exit codes and its outputs."""

from __future__ import annotations

import shutil
import json

import pytest
from hypothesis import given, strategies as st

from mmsnap_graph.app.cli import main

from _fuzz import CLI_FUZZ, one_line_data_error
from _shared import DATA


@pytest.fixture(scope="module")
def sample(tmp_path_factory):
    d = tmp_path_factory.mktemp("fuzz_more")
    path = d / "config_B_straight.h5"
    shutil.copy(DATA / "config_B_straight.h5", path)
    return path.read_bytes()


@CLI_FUZZ
@given(cut=st.floats(0.0, 0.95), flips=st.lists(st.tuples(st.integers(0, 4095),
                                                           st.integers(0, 7)), max_size=3))
def test_demo_on_a_damaged_sample_exits_1_naming_it(sample, tmp_path_factory, capsys, cut, flips):
    d = tmp_path_factory.mktemp("demo_data")
    data = bytearray(sample[: max(int(len(sample) * cut), 0)]) if cut > 0.01 else bytearray(sample)
    for at, bit in flips:
        if at < len(data):
            data[at] ^= 1 << bit
    if cut <= 0.01 and not flips:
        data = bytearray(b"not a recording")
    (d / "config_B_straight.h5").write_bytes(bytes(data))
    code = main(["demo", "--data", str(d), "-c", "B", "-n", "20", "--cube-frames", "0",
                 "--no-figures", "--no-progress", "--out", str(d / "out")])
    err = capsys.readouterr().err.strip().splitlines()
    if code == 0:  # a flip that hit nothing the demo reads
        return
    one_line_data_error(code, err, "config_B_straight.h5")


def test_demo_refuses_a_sample_that_is_a_directory(tmp_path, capsys):
    (tmp_path / "config_B_straight.h5").mkdir()
    assert main(["demo", "--data", str(tmp_path), "-c", "B", "-n", "20", "--no-figures",
                 "--out", str(tmp_path / "out"), "--no-progress"]) == 1
    assert "config_B_straight.h5" in capsys.readouterr().err


@pytest.mark.parametrize("frames, strict, holds, code", [
    (600, False, True, 0), (600, False, False, 1), (60, False, False, 0), (60, True, False, 1)])
def test_demo_exits_1_when_a_paper_check_does_not_hold(monkeypatch, tmp_path, capsys, frames,
                                                       strict, holds, code):
    """The demo's own steps are replaced by stubs; only the exit code is tested."""
    import types

    import mmsnap_graph.app.demo as demo
    import mmsnap_graph.app.report as report
    from mmsnap_graph.app.report import Check

    table = types.SimpleNamespace(text=lambda: "table")
    result = types.SimpleNamespace(cube_stretches=[], failures=[], seconds={})
    monkeypatch.setattr(demo, "run_demo", lambda *a, **k: result)
    for name in ("table_ii", "table_poses", "table_iii_track_fusion", "table_iii_truth"):
        monkeypatch.setattr(report, name, lambda *a, **k: table)
    monkeypatch.setattr(report, "levels_text", lambda *a, **k: "levels")
    monkeypatch.setattr(report, "write_json", lambda *a, **k: None)
    monkeypatch.setattr(report, "write_report", lambda *a, **k: tmp_path / "report.md")
    monkeypatch.setattr(report, "qualitative_checks",
                        lambda r: [Check(claim="a claim", holds=holds, detail="")])
    argv = ["demo", "--simulate", "-n", str(frames), "--no-figures", "--out", str(tmp_path),
            "--no-progress"] + (["--strict"] if strict else [])
    assert main(argv) == code
    if not holds:
        assert "a claim" in capsys.readouterr().err


@pytest.mark.slow
def test_demo_command_writes_tables_figures_and_report(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["demo", "--simulate", "-c", "B,C", "-n", "60", "--cube-frames", "3",
                 "--out", str(out), "--no-progress"]) == 0
    text = capsys.readouterr().out
    for needle in ("Table II", "Table III", "raw ADC cubes", "point clouds", "calibrate on one "
                   "trajectory, fuse the other", "Qualitative results"):
        assert needle in text
    report = (out / "report.md").read_text()
    pngs = sorted(p.name for p in out.glob("*.png"))
    assert {"calibration_tracks.png", "velocity_posteriors.png", "degeneracy_map.png",
            "timeseries_B_random.png", "timeseries_C_random.png"} <= set(pngs)
    for name in pngs:
        assert f"]({name})" in report
        assert (out / name).stat().st_size > 10_000
    data = json.loads((out / "results.json").read_text())
    assert set(data["fusion"]) == {"B/straight", "B/random", "C/straight", "C/random"}
    assert data["fusion"]["C/random"]["calibrated_on"] == "straight"
    assert data["wall_time_s"] > 0
    assert len(data["cube_stretches"]) == 1


def test_demo_command_rejects_bad_arguments(capsys, tmp_path):
    assert main(["demo", "--frames", "5", "--out", str(tmp_path)]) == 2
    assert "--frames must be >= 20, got 5" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["demo", "-c", "A,D"])
    assert main(["demo", "--data", str(tmp_path / "missing"), "--out", str(tmp_path)]) == 2
    assert "does not exist" in capsys.readouterr().err
