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


@pytest.mark.parametrize("content", ["empty", "foreign"])
def test_an_empty_or_foreign_hdf5_file_is_not_a_recording(tmp_path, capsys, content):
    """Before: `mmsnap info` exited 0 on it ("frame period nan ms") and
    --json printed NaN, which is not JSON."""
    from mmsnap_graph.app.cli import main
    from mmsnap_graph.errors import FileFormatError

    path = tmp_path / f"{content}.h5"
    with h5py.File(path, "w") as f:
        if content == "foreign":
            f["data"] = np.arange(3)
            f.attrs["frame_period_s"] = np.nan
    with pytest.raises(FileFormatError, match=f"{content}.h5 is an .*HDF5 file but not an "
                                              "mmsnap recording"):
        recording_info(path)
    for extra in ([], ["--json"]):
        assert main(["info", str(path), *extra]) == 1
        out = capsys.readouterr()
        assert out.out == "" and "not an mmsnap recording" in out.err


def test_info_json_is_json_where_a_value_is_not_finite(fused_b_file, tmp_path, capsys):
    import json
    import shutil

    from mmsnap_graph.app.cli import main

    path = tmp_path / "rec.h5"
    shutil.copy(fused_b_file, path)
    with h5py.File(path, "r+") as f:
        f.require_group("metadata").attrs["gain_db"] = np.nan
    assert main(["info", str(path), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)  # (Python reads NaN; other parsers do not)
    assert data["metadata"]["gain_db"] is None
