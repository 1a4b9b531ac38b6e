"""``mmsnap simulate``: the model switch, the options it builds, the cube size warning."""

from __future__ import annotations

import argparse

import numpy as np
from numpy.testing import assert_array_equal, assert_allclose
import pytest

from mmsnap_graph.app.cli import main
from mmsnap_graph.app.commands.simulate import cube_megabytes, simulation_options
from mmsnap_graph.io import read_recording
from mmsnap_graph.sim import CLEAN, SimulationOptions, simulate_recording


def test_model_switch_selects_real_or_clean(tmp_path, capsys):
    real, clean = tmp_path / "r.h5", tmp_path / "c.h5"
    assert main(["simulate", "-c", "B", "-n", "30", "-s", "2", "-l", "centroids", "-o", str(real),
                 "--no-progress"]) == 0
    out = capsys.readouterr().out
    # The summary says how many rows are not of a person, and which model ran.
    n_other = int(np.sum(read_recording(real).nodes["S1"].centroids.target_id < 0))
    assert f"({n_other} not of a person: static scene" in out and "real model" in out
    assert main(["simulate", "--model", "clean", "-c", "B", "-n", "30", "-s", "2", "-l",
                 "centroids", "-o", str(clean), "--no-progress"]) == 0
    r, c = read_recording(real), read_recording(clean)
    assert r.metadata["model"] == "real" and c.metadata["model"] == "clean"
    ref = simulate_recording("B", "straight", CLEAN, levels=("centroids",), n_frames=30, seed=2)
    assert_array_equal(c.nodes["S1"].centroids.range_m, ref.nodes["S1"].centroids.range_m)
    # The real model has static (zero-Doppler, unlabelled) rows the clean one has not.
    assert np.any(r.nodes["S1"].centroids.target_id == -1)
    assert np.all(c.nodes["S1"].centroids.target_id >= 0)


def test_cli_builds_the_same_options_object():
    args = argparse.Namespace(model="clean", frame_period=0.05, targets=2, cube_frames=3,
                              known_poses=True)
    assert simulation_options(args) == SimulationOptions(
        physics=None, frame_period_s=0.05, n_targets=2, cube_frames=3, known_poses=True)


def test_cube_level_warns_of_its_size_before_writing(tmp_path, capsys):
    out = tmp_path / "k.h5"
    assert main(["simulate", "--model", "clean", "-c", "B", "-n", "4", "-l", "cube",
                 "--cube-frames", "2", "-o", str(out), "--no-progress"]) == 0
    err = capsys.readouterr().err
    mb = cube_megabytes(SimulationOptions(cube_frames=2), 2, 4)
    assert abs(mb - 2 * 2 * 512 * 60 * 12 * 8 / 1e6) < 1e-9
    assert f"2 nodes x 2 frames = {mb:,.0f} MB" in err
    assert read_recording(out).nodes["S1"].cube.shape[0] == 2


def test_simulate_command_writes_the_library_result(tmp_path, capsys):
    out = tmp_path / "b.h5"
    rc = main(["simulate", "-c", "B", "-t", "random", "-n", "40", "-s", "3", "-l",
               "centroids,point_cloud,cube", "--cube-frames", "2", "-o", str(out),
               "--no-progress"])
    assert rc == 0
    assert "wrote" in capsys.readouterr().out
    rec = read_recording(out)
    # The command's default is the real physics.
    ref = simulate_recording("B", "random", SimulationOptions(cube_frames=2),
                             levels=("centroids", "point_cloud", "cube"), n_frames=40, seed=3)
    assert_array_equal(rec.truth.state, ref.truth.state)
    assert_array_equal(rec.nodes["S2"].point_cloud.range_m, ref.nodes["S2"].point_cloud.range_m)
    assert_array_equal(rec.nodes["S1"].cube, ref.nodes["S1"].cube)
    assert rec.nodes["S1"].pose is None
    # No scratch files left next to the output.
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b.h5"]


def test_simulate_command_custom_nodes_and_errors(tmp_path, capsys):
    out = tmp_path / "n.h5"
    assert main(["simulate", "--node", "S1=0,0,0", "--node", "S2=6,0,0", "--node", "S3=3,8,180",
                 "-l", "centroids", "-n", "10", "--known-poses", "-o", str(out)]) == 0
    rec = read_recording(out)
    assert rec.node_names == ["S1", "S2", "S3"]
    assert_allclose(rec.nodes["S3"].pose, [3, 8, np.pi])
    assert main(["simulate", "-o", str(out), "-n", "5"]) == 2
    assert "exists; pass --overwrite" in capsys.readouterr().err
    assert main(["simulate", "-o", str(tmp_path / "x.h5"), "-l", "cubes", "-n", "5"]) == 2
    assert "levels=" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["simulate", "--node", "S1=0,0", "-o", str(tmp_path / "y.h5")])
