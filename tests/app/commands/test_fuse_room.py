"""``mmsnap fuse --bounds / --bounds-cfg / --no-body-check / --no-learned-walls``:
the room-frame checks of fused rows from the command line."""

from __future__ import annotations

import numpy as np
import pytest

from mmsnap_graph.app.cli import main
from mmsnap_graph.data.results import Status
from mmsnap_graph.io.fused import read_fused


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    """Configuration B (S2 at (5 m, 5 m)), one walker, known poses."""
    path = tmp_path_factory.mktemp("room") / "sim.h5"
    assert main(["simulate", "-c", "B", "-t", "random", "-n", "120", "-l", "centroids",
                 "--seed", "3", "--known-poses", "-o", str(path), "--no-progress"]) == 0
    return path


def _fuse(recording, tmp_path, *extra):
    out = tmp_path / "fused.h5"
    code = main(["fuse", str(recording), "-o", str(out), "--no-progress", "--overwrite", *extra])
    return code, out


def test_bounds_flag_the_rows_outside_the_room(recording, tmp_path, capsys):
    assert _fuse(recording, tmp_path, "--no-body-check")[0] == 0
    free = read_fused(tmp_path / "fused.h5")
    xy = free.state[free.success, :2]
    cut = float(np.median(xy[:, 0]))                  # half the walk is "outside"
    capsys.readouterr()
    code, out = _fuse(recording, tmp_path, "--no-body-check", f"--bounds=-50,{cut},-50,50")
    assert code == 0
    text = capsys.readouterr().out
    boxed = read_fused(out)
    outside = free.success & (free.state[:, 0] > cut)
    np.testing.assert_array_equal(boxed.success, free.success & ~outside)
    assert np.all(boxed.status[outside] == Status.OUTSIDE_BOUNDS)
    assert f"flagged {int(outside.sum())} target(s) outside the bounds" in text
    assert "room bounds x -50.." in text


def test_bounds_from_a_people_tracking_cfg(recording, tmp_path, capsys):
    cfg = tmp_path / "people.cfg"
    cfg.write_text("% 3D people tracking\nsensorPosition 2 0 15\n"
                   "boundaryBox -50 50 -50 50 0 3\nstaticBoundaryBox -1 1 0.5 2 0 3\n"
                   "presenceBoundaryBox -3 3 0.5 7.5 0 3\n")
    code, out = _fuse(recording, tmp_path, "--bounds-cfg", str(cfg))
    assert code == 0
    text = capsys.readouterr().out
    assert "room bounds x -50..50 m" in text and "static bounds x -1..1 m" in text
    assert read_fused(out).success.any()


def test_in_front_flags_the_rows_behind_a_radar(recording, tmp_path, capsys):
    assert _fuse(recording, tmp_path, "--no-body-check")[0] == 0
    free = read_fused(tmp_path / "fused.h5")
    capsys.readouterr()
    code, out = _fuse(recording, tmp_path, "--no-body-check", "--in-front")
    assert code == 0 and "targets in front of every radar" in capsys.readouterr().out
    front = read_fused(out)
    poses = free.node_poses
    ahead = np.stack([-np.sin(p[2]) * (free.state[:, 0] - p[0])
                      + np.cos(p[2]) * (free.state[:, 1] - p[1]) for p in poses], axis=1)
    np.testing.assert_array_equal(front.success, free.success & np.all(ahead >= 0, axis=1))


def test_one_target_per_body_is_the_default_and_switches_off(recording, tmp_path, capsys):
    code, out = _fuse(recording, tmp_path)
    assert code == 0 and "one target per 0.5 m" in capsys.readouterr().out
    on = read_fused(out)
    _fuse(recording, tmp_path, "--no-body-check")
    off = read_fused(tmp_path / "fused.h5")
    assert "no body check" in capsys.readouterr().out
    assert not np.any(off.status == Status.DUPLICATE)
    np.testing.assert_array_equal(on.success | (on.status == Status.DUPLICATE), off.success)


@pytest.mark.parametrize("extra, words", [
    (["--bounds", "1,2,3"], "XMIN,XMAX,YMIN,YMAX"),
    (["--bounds=2,1,0,1"], "x_min < x_max"),
    (["--bounds=0,1,0,1", "--bounds-cfg", "x.cfg"], "not allowed with argument --bounds"),
])
def test_bad_bounds_are_usage_errors(recording, tmp_path, capsys, extra, words):
    try:
        code = _fuse(recording, tmp_path, *extra)[0]
    except SystemExit as exc:                          # argparse
        code = exc.code
    assert code == 2
    assert words in capsys.readouterr().err


def test_a_cfg_without_boxes_is_an_error(recording, tmp_path, capsys):
    cfg = tmp_path / "oob.cfg"
    cfg.write_text("sensorStop\nframeCfg 0 2 16 0 50 1 0\n")
    assert _fuse(recording, tmp_path, "--bounds-cfg", str(cfg))[0] == 2
    assert "no boundaryBox" in capsys.readouterr().err


@pytest.fixture(scope="module")
def mirrored(tmp_path_factory):
    """Three nodes, one walker, known poses, 20% of each node's centroids
    with a mirror image through a wall of the room (clean model)."""
    from _shared import POSES_BC
    from mmsnap_graph.io import write_recording
    from mmsnap_graph.sim import SimulationOptions, simulate_recording
    from mmsnap_graph.sim.real.ghosts import ghost_centroids

    rec = simulate_recording({"S1": POSES_BC[0], "S2": POSES_BC[1], "S3": POSES_BC[2]},
                             "random", SimulationOptions(physics=None, known_poses=True),
                             levels=("centroids",), n_frames=300, seed=10)
    path = tmp_path_factory.mktemp("walls") / "mirror.h5"
    write_recording(path, ghost_centroids(rec, "mirror", 0.2, seed=110))
    return path, rec.truth


def test_learned_walls_flag_the_mirror_images(mirrored, tmp_path, capsys):
    path, truth = mirrored
    sigmas = ["--sigmas", "0.05", "0.08", "0.1"]
    assert _fuse(path, tmp_path, *sigmas)[0] == 0
    text = capsys.readouterr().out
    fused = read_fused(tmp_path / "fused.h5")
    walled = fused.status == Status.OUTSIDE_BOUNDS
    err = np.hypot(*(fused.state[:, :2] - truth.state[fused.frame, :2]).T)
    assert "walls learned from multipath images" in text and "learned wall of S" in text
    assert f"({int(walled.sum())} beyond a learned wall)" in text
    assert walled.any() and np.all(err[walled] > 1.0)           # images, never the walker
    assert np.all(err[fused.success] < 0.5)
    # The switch, and a room box, which replaces the learned walls.
    for extra in (["--no-learned-walls"], ["--bounds=-50,50,-50,50"]):
        assert _fuse(path, tmp_path, *sigmas, *extra)[0] == 0
        text = capsys.readouterr().out
        assert "learned wall" not in text and "walls learned" not in text
        assert not np.any(read_fused(tmp_path / "fused.h5").status == Status.OUTSIDE_BOUNDS)
