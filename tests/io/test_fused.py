"""The /fused group (mmsnap_graph.io.fused): written, read back, replaced, and its errors."""

from __future__ import annotations

import json

import h5py
import numpy as np
import pytest

from mmsnap_graph.errors import FileFormatError
from mmsnap_graph.data.results import Status
from mmsnap_graph.fusion.recording.sequence import fuse_recording
from mmsnap_graph.io.fused import read_fused, write_fused
from mmsnap_graph.io import read_recording, write_recording
from _fusion import config


@pytest.fixture
def recordings(two_target_recordings):
    """Two walking targets, 10 % missed centroids, per configuration (conftest)."""
    return two_target_recordings


def test_write_and_read_fused_round_trip(recordings, tmp_path):
    rec = recordings["A"]
    path = write_recording(tmp_path / "rec.h5", rec)
    fused = fuse_recording(rec, config(mode="ml"))
    write_fused(path, fused)
    back = read_fused(path)
    for name in ("frame", "target", "label", "detection_index", "observed", "success", "status",
                 "iterations", "track_id"):
        np.testing.assert_array_equal(getattr(back, name), getattr(fused, name))
    for name in ("state", "covariance", "laplace_covariance", "final_cost", "degeneracy", "node_poses"):
        np.testing.assert_array_equal(getattr(back, name), getattr(fused, name))
    assert back.mode == "ml" and back.prior_mean is None and list(back.message) == list(fused.message)
    # ML frames seen by one node are singular: code 2 of the file contract.
    assert set(np.unique(back.status)) <= {Status.OK, Status.SINGULAR}
    assert (back.status == Status.SINGULAR).any()
    with h5py.File(path, "r") as f:
        codes = json.loads(f["fused"].attrs["status_messages"])
    assert sorted(int(c) for c in codes) == [0, 1, 2, 3, 4, 5, 9, 10, 11, 12]
    # The recording itself is intact, and a second write replaces /fused.
    assert read_recording(path).node_names == rec.node_names
    write_fused(path, fuse_recording(rec, config()))
    assert read_fused(path).mode == "map"


def test_write_fused_to_a_new_file_leaves_the_original(recordings, tmp_path):
    path = write_recording(tmp_path / "rec.h5", recordings["A"])
    out = write_fused(path, fuse_recording(recordings["A"], config()), output=tmp_path / "out.h5")
    with h5py.File(path, "r") as f:
        assert "fused" not in f
    assert len(read_fused(out)) > 0


def test_fused_errors(tmp_path, recordings):
    with pytest.raises(FileFormatError, match="does not exist"):
        read_fused(tmp_path / "nope.h5")
    path = write_recording(tmp_path / "rec.h5", recordings["A"])
    with pytest.raises(FileFormatError, match="has no /fused group"):
        read_fused(path)
    write_fused(path, fuse_recording(recordings["A"], config()))
    with h5py.File(path, "r+") as f:
        del f["fused/covariance"]
    with pytest.raises(FileFormatError, match="/fused/covariance is missing"):
        read_fused(path)
    with pytest.raises(FileFormatError, match="does not exist"):
        write_fused(tmp_path / "nope.h5", fuse_recording(recordings["A"], config()))


def test_a_file_without_person_ids_reads_with_none(recordings, tmp_path):
    """Format 1.1 had no ``track_id``: such a file reads, with ``track_id`` None."""
    path = write_recording(tmp_path / "rec.h5", recordings["B"])
    fused = fuse_recording(recordings["B"], config())
    assert fused.track_id is not None and (fused.track_id >= 0).any()
    write_fused(path, fused)
    with h5py.File(path, "a") as f:
        del f["fused/track_id"]
        f["fused"].attrs["format_version"] = "1.1"
    back = read_fused(path)
    assert back.track_id is None and len(back) == len(fused)


def test_person_ids_of_the_wrong_shape_are_a_format_error(recordings, tmp_path):
    path = write_recording(tmp_path / "rec.h5", recordings["B"])
    write_fused(path, fuse_recording(recordings["B"], config()))
    with h5py.File(path, "a") as f:
        del f["fused/track_id"]
        f["fused/track_id"] = np.zeros(3, dtype=np.int64)
    with pytest.raises(FileFormatError, match=r"track_id has shape \(3,\)"):
        read_fused(path)


@pytest.mark.parametrize("edit", ["zero", "negative", "nan", "asymmetric", "nan state"])
def test_a_succeeded_row_without_a_proper_covariance_is_named_on_read(recordings, tmp_path, edit):
    """Before: /fused rows with success=True and a zero or negative covariance
    were read as they were: export printed sigma 0.0, Stone Soup received
    covariances that are not positive definite, evaluate dropped the rows."""
    path = write_recording(tmp_path / "rec.h5", recordings["B"])
    fused = fuse_recording(recordings["B"], config())
    write_fused(path, fused)
    rows = np.flatnonzero(fused.success)[[3, 7]]
    with h5py.File(path, "a") as f:
        cov = f["fused/covariance"][()]
        for r in rows:
            cov[r] = {"zero": np.zeros((4, 4)), "negative": -np.eye(4), "nan": np.full((4, 4), np.nan),
                      "asymmetric": cov[r] + np.triu(np.ones((4, 4)), 1),
                      "nan state": cov[r]}[edit]
            if edit == "nan state":
                f["fused/x_m"][r] = np.nan
        f["fused/covariance"][...] = cov
    import re

    with pytest.raises(FileFormatError, match=re.escape(
            f"rows {rows.tolist()} (frames {fused.frame[rows].tolist()}; 2 in all) have "
            "success=True but a covariance")):
        read_fused(path)
