"""``mmsnap simulate``."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from mmsnap_graph.app.cli import main
from mmsnap_graph.io import read_recording
from mmsnap_graph.sim import SimulationOptions, simulate_recording


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


@pytest.mark.slow
def test_python_dash_m_runs_the_command_line(tmp_path):
    """``python -m mmsnap_graph`` is the ``mmsnap`` command."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [str(root)] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]))
    help_ = subprocess.run([sys.executable, "-m", "mmsnap_graph", "--help"], capture_output=True,
                           text=True, env=env, cwd=tmp_path, timeout=120)
    assert help_.returncode == 0, help_.stderr
    for command in ("process", "simulate", "calibrate", "fuse", "demo", "evaluate"):
        assert command in help_.stdout
    out = tmp_path / "a.h5"
    run = subprocess.run([sys.executable, "-m", "mmsnap_graph", "simulate", "-c", "A", "-n", "20",
                          "-s", "5", "-l", "centroids", "-o", str(out), "--no-progress"],
                         capture_output=True, text=True, env=env, cwd=tmp_path, timeout=300)
    assert run.returncode == 0, run.stderr
    rec = read_recording(out)
    ref = simulate_recording("A", "straight", n_frames=20, seed=5, levels=("centroids",))
    assert_array_equal(rec.truth.state, ref.truth.state)
    # Errors come back as the command's exit status 2, not a traceback.
    bad = subprocess.run([sys.executable, "-m", "mmsnap_graph", "demo", "--frames", "5",
                          "-o", str(tmp_path / "x")], capture_output=True, text=True, env=env,
                         cwd=tmp_path, timeout=120)
    assert bad.returncode == 2 and "--frames must be >= 20" in bad.stderr
