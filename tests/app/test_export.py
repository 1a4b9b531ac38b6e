"""`mmsnap export`: /fused and /calibration as CSV and JSON lines, checked
against the readers' arrays."""

from __future__ import annotations

import csv
import io
import json

import numpy as np
import pytest

from mmsnap_graph.app.cli import main
from mmsnap_graph.io.calibration import read_calibration
from mmsnap_graph.io.fused import read_fused


def test_fused_csv_matches_the_reader(fused_b_file, capsys):
    capsys.readouterr()
    assert main(["export", str(fused_b_file), "fused"]) == 0
    rows = list(csv.DictReader(io.StringIO(capsys.readouterr().out)))
    fused = read_fused(fused_b_file)
    assert len(rows) == len(fused.frame)
    ok = np.flatnonzero(fused.success)[0]
    row = rows[ok]
    assert int(row["frame"]) == fused.frame[ok]
    np.testing.assert_allclose([float(row[k]) for k in ("x_m", "y_m", "vx_mps", "vy_mps")],
                               fused.state[ok], rtol=1e-12)
    assert float(row["sigma_x_m"]) == pytest.approx(np.sqrt(fused.covariance[ok][0, 0]))
    assert row["success"] == "True" and row["nodes"] == "S1 S2"
    assert [int(r["track_id"]) for r in rows] == fused.track_id.tolist()
    assert all(int(r["track_id"]) == -1 for r, ok in zip(rows, fused.success) if not ok)


def test_jsonl_keeps_the_full_covariance(fused_b_file, tmp_path):
    out = tmp_path / "fused.jsonl"
    assert main(["export", str(fused_b_file), "fused", "-o", str(out)]) == 0
    lines = out.read_text().splitlines()
    fused = read_fused(fused_b_file)
    first = json.loads(lines[0])
    np.testing.assert_allclose(np.array(first["covariance"]).reshape(4, 4), fused.covariance[0])
    assert len(lines) == len(fused.frame)


def test_calibration_csv_has_degrees_and_sigmas(fused_b_file, capsys):
    capsys.readouterr()
    assert main(["export", str(fused_b_file), "calibration"]) == 0
    rows = {r["node"]: r for r in csv.DictReader(io.StringIO(capsys.readouterr().out))}
    cal = read_calibration(fused_b_file)
    s2 = rows["S2"]
    assert float(s2["phi_deg"]) == pytest.approx(np.degrees(cal.poses["S2"][2]))
    assert float(s2["sigma_x_m"]) == pytest.approx(np.sqrt(cal.covariances["S2"][0, 0]))


def test_csv_cells_a_spreadsheet_would_run_are_neutralised():
    """Before: node names such as `+SUM(1)` or `=cmd|...` went out as they
    are, and a spreadsheet ran them as formulas."""
    from mmsnap_graph.app.export import write_table

    names = ["=cmd|' /C calc'!A0", "+SUM(1)", "-2+3", "@SUM(A1)", "\tx", "\rx", "S1", "a=b"]
    rows = [{"node": n, "x_m": -1.5, "calibrated": True} for n in names]
    text = write_table(rows, ("node", "x_m", "calibrated"), "csv")
    back = list(csv.DictReader(io.StringIO(text, newline="")))
    assert [r["node"] for r in back] == ["'" + n for n in names[:6]] + ["S1", "a=b"]
    assert all(r["x_m"] == "-1.5" for r in back)  # a negative number stays a number
    lines = write_table(rows, ("node", "x_m"), "jsonl").splitlines()
    assert [json.loads(ln)["node"] for ln in lines] == names  # JSON keeps the text


def test_a_file_fused_before_person_ids_exports_an_empty_track_id(fused_b_file, tmp_path, capsys):
    import shutil

    import h5py

    old = tmp_path / "old.h5"
    shutil.copy(fused_b_file, old)
    with h5py.File(old, "a") as f:
        del f["fused/track_id"]
        f["fused"].attrs["format_version"] = "1.1"
    capsys.readouterr()
    assert main(["export", str(old), "fused"]) == 0
    rows = list(csv.DictReader(io.StringIO(capsys.readouterr().out)))
    assert rows and all(r["track_id"] == "" for r in rows)
    assert main(["export", str(old), "fused", "--format", "jsonl"]) == 0
    assert json.loads(capsys.readouterr().out.splitlines()[0])["track_id"] is None
