"""Hand-over to trackers: ``/fused`` carries time stamps and the prior-free
information form; ``mmsnap evaluate`` says when the NEES check fails."""

from __future__ import annotations

import dataclasses
import json

import h5py
import numpy as np
import pytest

from mmsnap_graph.app.cli import main
from mmsnap_graph.app.evaluation import evaluate_recording, failed_checks
from mmsnap_graph.io import write_fused, write_recording
from mmsnap_graph.io.fused import read_fused


def test_fused_file_has_time_s_and_the_information_form(recording_b_known_poses, fused_b_map, tmp_path):
    path = tmp_path / "rec.h5"
    write_recording(path, recording_b_known_poses)
    write_fused(path, fused_b_map)
    with h5py.File(path, "r") as f:
        g = f["fused"]
        np.testing.assert_allclose(g["time_s"][()], fused_b_map.frame * recording_b_known_poses.frame_period_s)
        assert g["information"].shape == (len(fused_b_map), 4, 4)
        assert g["information_vector"].shape == (len(fused_b_map), 4)
        assert g.attrs["frame_period_s"] == recording_b_known_poses.frame_period_s
        assert "time_origin_s" not in g.attrs
    back = read_fused(path)
    np.testing.assert_allclose(back.time_s, fused_b_map.frame * recording_b_known_poses.frame_period_s)
    np.testing.assert_array_equal(back.information, fused_b_map.information)
    np.testing.assert_array_equal(back.information_vector, fused_b_map.information_vector)
    assert back.frame_period_s == recording_b_known_poses.frame_period_s and back.time_origin_s is None


def test_time_stamps_of_a_time_stamped_recording(recording_b_known_poses, fused_b_map, tmp_path):
    path = tmp_path / "stamped.h5"
    rec = dataclasses.replace(recording_b_known_poses, frame_period_s=0.05,
                              metadata={**recording_b_known_poses.metadata, "time_origin_s": 1.7e9 + 0.25})
    write_recording(path, rec)
    # A sequence without a clock of its own takes the file's.
    write_fused(path, dataclasses.replace(fused_b_map, time_s=None, frame_period_s=None,
                                          time_origin_s=None))
    back = read_fused(path)
    assert back.time_origin_s == pytest.approx(1.7e9 + 0.25)
    np.testing.assert_allclose(back.time_s, fused_b_map.frame * 0.05)
    # Time stamps given with the sequence win over the file's clock.
    own = dataclasses.replace(fused_b_map, time_s=fused_b_map.frame * 0.2 + 1.0)
    write_fused(path, own)
    np.testing.assert_allclose(read_fused(path).time_s, fused_b_map.frame * 0.2 + 1.0)


def test_a_file_of_format_1_0_still_reads(recording_b_known_poses, fused_b_map, tmp_path):
    path = tmp_path / "old.h5"
    write_recording(path, recording_b_known_poses)
    write_fused(path, fused_b_map)
    with h5py.File(path, "r+") as f:
        g = f["fused"]
        for name in ("time_s", "information", "information_vector"):
            del g[name]
        del g.attrs["frame_period_s"]
        g.attrs["format_version"] = "1.0"
    back = read_fused(path)
    np.testing.assert_allclose(back.time_s, fused_b_map.frame * recording_b_known_poses.frame_period_s)
    np.testing.assert_allclose(back.information, fused_b_map.information, rtol=1e-12)
    np.testing.assert_allclose(back.information_vector, fused_b_map.information_vector,
                               rtol=1e-12, atol=1e-12)


# ----------------------------------------------------------------------------
# mmsnap evaluate: the NEES check
# ----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def files(recording_b_known_poses, fused_b_map, tmp_path_factory):
    """The recording with its honest /fused, and a copy whose covariances
    are a quarter of the honest ones (over-confident)."""
    d = tmp_path_factory.mktemp("nees")
    good, bad = d / "good.h5", d / "bad.h5"
    write_recording(good, recording_b_known_poses)
    write_fused(good, fused_b_map)
    write_recording(bad, recording_b_known_poses)
    write_fused(bad, dataclasses.replace(fused_b_map, covariance=fused_b_map.covariance / 4.0))
    return good, bad


def test_evaluate_reports_a_failed_nees_check(files, capsys):
    good, bad = files
    assert main(["evaluate", str(bad)]) == 0           # reported, not an error
    text = capsys.readouterr().out
    assert "FAILED: NEES check failed" in text and "outside the 95% interval" in text
    assert "over-confident" in text
    assert main(["evaluate", str(bad), "--check"]) == 1
    capsys.readouterr()
    assert main(["evaluate", str(bad), "--check", "--json"]) == 1
    captured = capsys.readouterr()
    data = json.loads(captured.out)
    assert data["fused"]["nees"]["passed"] is False
    lo, hi = data["fused"]["nees"]["interval_95"]
    assert data["fused"]["nees"]["mean"] > hi
    assert f"{data['fused']['nees']['mean']:.2f}" in data["failed_checks"][0]
    assert f"({lo:.2f}, {hi:.2f})" in data["failed_checks"][0]
    assert "NEES check failed" in captured.err


def test_evaluate_check_passes_on_honest_covariances(files, capsys):
    good, _ = files
    assert main(["evaluate", str(good), "--check"]) == 0
    text = capsys.readouterr().out
    assert "NEES check passed" in text and "FAILED" not in text


def test_failed_checks_of_an_under_confident_covariance(recording_b_known_poses, fused_b_map):
    m = evaluate_recording(recording_b_known_poses, fused=dataclasses.replace(
        fused_b_map, covariance=fused_b_map.covariance * 4.0))
    assert m["fused"]["nees"]["passed"] is False
    assert m["failed_checks"] == failed_checks(m) and "under-confident" in m["failed_checks"][0]
    assert failed_checks({"fused": None}) == []
