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


@pytest.fixture(scope="module")
def fused_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("export") / "rec.h5"
    assert main(["simulate", "-c", "B", "-t", "random", "-l", "centroids", "--model", "clean", "-n", "80",
                 "--seed", "4", "-o", str(path)]) == 0
    assert main(["calibrate", str(path)]) == 0
    assert main(["fuse", str(path)]) == 0
    return path


def test_fused_csv_matches_the_reader(fused_file, capsys):
    capsys.readouterr()
    assert main(["export", str(fused_file), "fused"]) == 0
    rows = list(csv.DictReader(io.StringIO(capsys.readouterr().out)))
    fused = read_fused(fused_file)
    assert len(rows) == len(fused.frame)
    ok = np.flatnonzero(fused.success)[0]
    row = rows[ok]
    assert int(row["frame"]) == fused.frame[ok]
    np.testing.assert_allclose([float(row[k]) for k in ("x_m", "y_m", "vx_mps", "vy_mps")],
                               fused.state[ok], rtol=1e-12)
    assert float(row["sigma_x_m"]) == pytest.approx(np.sqrt(fused.covariance[ok][0, 0]))
    assert row["success"] == "True" and row["nodes"] == "S1 S2"


def test_jsonl_keeps_the_full_covariance(fused_file, tmp_path):
    out = tmp_path / "fused.jsonl"
    assert main(["export", str(fused_file), "fused", "-o", str(out)]) == 0
    lines = out.read_text().splitlines()
    fused = read_fused(fused_file)
    first = json.loads(lines[0])
    np.testing.assert_allclose(np.array(first["covariance"]).reshape(4, 4), fused.covariance[0])
    assert len(lines) == len(fused.frame)


def test_calibration_csv_has_degrees_and_sigmas(fused_file, capsys):
    capsys.readouterr()
    assert main(["export", str(fused_file), "calibration"]) == 0
    rows = {r["node"]: r for r in csv.DictReader(io.StringIO(capsys.readouterr().out))}
    cal = read_calibration(fused_file)
    s2 = rows["S2"]
    assert float(s2["phi_deg"]) == pytest.approx(np.degrees(cal.poses["S2"][2]))
    assert float(s2["sigma_x_m"]) == pytest.approx(np.sqrt(cal.covariances["S2"][0, 0]))


def test_export_before_fuse_names_the_command(tmp_path, capsys):
    path = tmp_path / "bare.h5"
    assert main(["simulate", "-c", "A", "-t", "straight", "-l", "centroids", "--model", "clean", "-n", "20",
                 "-o", str(path)]) == 0
    capsys.readouterr()
    assert main(["export", str(path), "fused"]) == 1
    assert f"run `mmsnap fuse {path}` first" in capsys.readouterr().err


def test_export_refuses_to_replace_a_file_without_overwrite(fused_file, tmp_path, capsys):
    out = tmp_path / "t.csv"
    out.write_text("keep me")
    assert main(["export", str(fused_file), "calibration", "-o", str(out)]) == 2
    assert out.read_text() == "keep me"
    assert main(["export", str(fused_file), "calibration", "-o", str(out), "--overwrite"]) == 0
    assert out.read_text().startswith("node,")
