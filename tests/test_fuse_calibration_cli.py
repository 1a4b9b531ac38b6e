"""``mmsnap fuse`` takes the calibration's pose covariances and clock offsets
by default (issue 11 item 5, issue 12 item 1), and options turn them off."""

import numpy as np
import pytest

from mmsnap_graph.app.cli import main
from mmsnap_graph.io import read_fused


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    path = tmp_path_factory.mktemp("fusecal") / "rec.h5"
    assert main(["simulate", "--model", "clean", "-c", "C", "-l", "centroids", "-n", "300", "-s", "2",
                 "-o", str(path)]) == 0
    assert main(["process", str(path), "--centroids-only", "--no-progress"]) == 0
    assert main(["calibrate", str(path)]) == 0
    return path


def test_default_fuse_includes_the_pose_covariances_and_offsets(calibrated, capsys):
    capsys.readouterr()
    assert main(["fuse", str(calibrated), "--no-progress"]) == 0
    text = capsys.readouterr().out
    assert "pose covariances of S2 included" in text and "clock offsets applied: S2" in text
    with_poses = read_fused(calibrated)
    assert main(["fuse", str(calibrated), "--no-progress", "--no-pose-covariance"]) == 0
    assert "poses exact" in capsys.readouterr().out
    exact = read_fused(calibrated)
    # Same estimates; the calibration's uncertainty only widens the covariance.
    np.testing.assert_array_equal(exact.state, with_poses.state)
    ok = exact.success & with_poses.success
    grow = np.linalg.eigvalsh(with_poses.covariance[ok] - exact.covariance[ok])
    assert np.all(grow > -1e-12) and np.median(grow[:, -1]) > 0
    assert main(["fuse", str(calibrated), "--no-progress", "--no-time-offsets"]) == 0
    assert "clocks as recorded" in capsys.readouterr().out
    assert not np.array_equal(read_fused(calibrated).state, with_poses.state)


def test_a_calibration_json_gives_poses_and_covariances(calibrated, capsys):
    json_path = calibrated.with_name("rec.calibration.json")
    assert json_path.exists()
    capsys.readouterr()
    out = calibrated.with_name("copy.h5")
    assert main(["fuse", str(calibrated), "--calibration", str(json_path), "--no-progress",
                 "--no-time-offsets", "-o", str(out)]) == 0
    assert "pose covariances of S2 included" in capsys.readouterr().out
    assert main(["fuse", str(calibrated), "--covariance", "grid", "--grid-points", "5",
                 "--no-progress", "-o", str(out), "--overwrite"]) == 0
    assert "pose covariances need --covariance laplace" in capsys.readouterr().out
