"""`mmsnap info` and :func:`recording_info`: what a recording holds, read
without loading it, checked against h5py reads of the same file."""

from __future__ import annotations


import h5py
import numpy as np
import pytest

from mmsnap_graph.app.recording_info import format_info, recording_info


def test_info_counts_match_the_file(fused_b_file):
    info = recording_info(fused_b_file)
    with h5py.File(fused_b_file, "r") as f:
        assert info["frame_period_s"] == pytest.approx(float(f.attrs["frame_period_s"]))
        for name in ("S1", "S2"):
            frames = f[f"nodes/{name}/centroids/frame"][()]
            level = info["nodes"][name]["levels"]["centroids"]
            assert level["rows"] == frames.size
            assert level["frames"] == np.unique(frames).size
            assert (level["first_frame"], level["last_frame"]) == (frames.min(), frames.max())
        success = f["fused/success"][()]
        assert info["fused"]["rows"] == success.size
        assert info["fused"]["succeeded"] == int(success.sum())
        assert sum(info["fused"]["status_counts"].values()) == success.size
        pose = f["calibration/pose"][1]
    assert info["calibration"]["nodes"]["S2"]["pose"] == pytest.approx(pose.tolist())
    assert info["truth"] is True
    assert info["frames"]["duration_s"] == pytest.approx(120 * info["frame_period_s"])


def test_info_text_has_units_and_degrees(fused_b_file):
    text = format_info(recording_info(fused_b_file))
    phi = recording_info(fused_b_file)["calibration"]["nodes"]["S2"]["pose"][2]
    assert f"phi {np.degrees(phi):+.2f} deg" in text
    assert "frame period 150.00 ms" in text
    assert "status 0 converged" in text
