"""``mmsnap calibrate`` (app.commands.calibrate): a summary a radar engineer
reads (units on every sigma, terms explained, one fact a line), ``--json``
printing and ``--json-out`` writing, the progress bar."""

from __future__ import annotations

import json
import re
import os

import numpy as np
import pytest

from mmsnap_graph.app.cli import main
from mmsnap_graph.app.commands.calibrate import noise_lines
from mmsnap_graph.app.runs import calibrate_and_store
from mmsnap_graph.data.noise import MeasurementNoise, NodeNoiseEstimate, NoiseEstimate
from mmsnap_graph.io import write_recording

#: A value with its unit, as the summary prints every sigma.
_SIGMA = re.compile(r"^\s+(range|omega|doppler)\s+[0-9.e+-]+ (m|rad|m/s):")


@pytest.fixture(scope="module")
def recording_path(recording_c_random, tmp_path_factory):
    path = tmp_path_factory.mktemp("calibrate") / "rec.h5"
    write_recording(path, recording_c_random)
    return path


@pytest.fixture(scope="module")
def calibrated(recording_path, tmp_path_factory):
    """The printed summary of one run (``--no-write``: the file is shared)."""
    js = tmp_path_factory.mktemp("calibrate_json") / "cal.json"
    return recording_path, js


def test_summary_has_units_one_fact_a_line_and_says_the_terms(calibrated, capsys):
    path, js = calibrated
    assert main(["calibrate", str(path), "--no-write", "--json-out", str(js),
                 "--no-progress", "--overwrite"]) == 0
    out = capsys.readouterr().out
    lines = out.splitlines()
    sigma_lines = [line for line in lines if _SIGMA.match(line)]
    assert len(sigma_lines) == 3 * 2, out  # three sigmas of each of the two nodes, with units
    assert "omega = pi sin(theta)" in out and "heading phi (the array axis) in degrees" in out
    assert "estimators: network = " in out
    # The outcome's facts are on lines of their own, not one long line.
    assert max(len(line) for line in lines) < 200, max(lines, key=len)
    (ok,) = [k for k, line in enumerate(lines) if line.startswith("ok: ")]
    assert sum(line.startswith("  ") for line in lines[ok + 1:ok + 4]) == 3
    assert "range 0.0" in out and re.search(r"sigmas estimated from residuals for the joint "
                                            r"graph: range [0-9.]+ m ", out)
    assert f"wrote {js}" in out


def test_not_identified_sigma_says_why_and_what_is_used():
    fallback = MeasurementNoise()
    est = NoiseEstimate(nodes={"S1": NodeNoiseEstimate(
        noise=MeasurementNoise(range_m=0.02, omega_rad=fallback.omega_rad, doppler_mps=0.09),
        identified=(True, False, True), n_residuals=(500, 0, 480),
        method="network+temporal, pooled, tails x1.10/1.00/1.30",
        reasons=("", "12 usable differences of its own centroid sequence (4.0 dof); "
                     "20 dof needed", ""))})
    text = "\n".join(noise_lines(est))
    assert "range   0.02 m: estimated from 500 residuals, x1.10 for heavy tails" in text
    assert (f"omega   {fallback.omega_rad:.4g} rad: NOT identified, the data cannot pin it "
            f"down; this fallback value is used instead\n      why: 12 usable") in text
    assert "doppler 0.09 m/s: estimated from 480 residuals, x1.30 for heavy tails" in text
    assert "heavy tails: " in text and "dof: degrees of freedom" in text
    assert "(estimator: network+temporal, pooled)" in text


def test_json_prints_the_calibration_and_json_out_writes_it(calibrated, capsys):
    path, js = calibrated
    assert main(["calibrate", str(path), "--no-write", "--json", "--json-out", str(js),
                 "--no-progress", "--overwrite"]) == 0
    captured = capsys.readouterr()
    printed = json.loads(captured.out)  # stdout holds the JSON alone
    assert printed == json.loads(js.read_text())
    assert set(printed["nodes"]) == {"S1", "S2"}
    # The file is in radians: S2 of configuration C faces S1 (about pi).
    assert abs(abs(printed["nodes"]["S2"]["pose"][2]) - np.pi) < 0.1
    assert "reference S1" in captured.err and f"wrote {js}" in captured.err


def test_calibrate_and_store_draws_a_bar_on_request(recording_path, tmp_path, capsys):
    calibrate_and_store(recording_path, json_path=tmp_path / "a.json", write=False,
                        progress=True)
    assert "calibrate" in capsys.readouterr().err
    calibrate_and_store(recording_path, json_path=tmp_path / "b.json", write=False)
    assert capsys.readouterr().err == ""


def test_calibrate_keeps_at_most_one_temporary_copy_on_disk(recording_b_file, tmp_path,
                                                            monkeypatch):
    rec = tmp_path / "rec.h5"
    rec.write_bytes(recording_b_file.read_bytes())
    size = rec.stat().st_size
    seen = []
    real_replace = os.replace

    def spy(src, dst, *args, **kwargs):
        # At the moment a finished temporary replaces its target, every
        # temporary copy of the recording is on disk.
        temps = [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]
        seen.append((len(temps), sum(p.stat().st_size for p in temps)))
        return real_replace(src, dst, *args, **kwargs)

    monkeypatch.setattr(os, "replace", spy)
    assert main(["calibrate", str(rec)]) == 0
    assert seen, "calibrate wrote no temporary copy"
    assert max(n for n, _ in seen) == 1
    assert max(b for _, b in seen) < 2 * size
