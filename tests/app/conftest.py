"""Fixtures of the application's tests (tests/conftest.py holds the shared
simulated recordings)."""

from __future__ import annotations

import pytest

from _shared import DATA


@pytest.fixture(scope="session")
def demo_on_samples():
    """The demo's pipeline (``run_demo``) on the sample recordings, first 300
    frames: six runs, calibrate on one trajectory and fuse the other. Slow
    (about a minute); shared by the demo and report tests."""
    from mmsnap_graph.app import demo

    if not demo.sample_path(DATA, "C", "straight").is_file():
        pytest.skip("sample recordings missing (python data/make_samples.py)")
    return demo.run_demo(demo.DemoConfig(n_frames=300, cube_frames=0), data_dir=DATA)


@pytest.fixture(scope="session")
def calibrated_c_file(tmp_path_factory):
    """Path of ``rec.h5``: configuration C, 300 frames of centroids (the clean
    model: its clocks give S2 an offset for calibrate to find), processed and
    calibrated by the CLI: node poses, /calibration with pose covariances and
    S2's clock offset, /noise from the data, ``rec.calibration.json`` beside
    it. Shared: read it, or copy it (with the JSON) before changing it."""
    from mmsnap_graph.app.cli import main

    path = tmp_path_factory.mktemp("calibrated_c") / "rec.h5"
    assert main(["simulate", "-c", "C", "-l", "centroids", "-n", "300", "-s", "2",
                 "--model", "clean", "-o", str(path)]) == 0
    assert main(["process", str(path), "--centroids-only", "--no-progress"]) == 0
    assert main(["calibrate", str(path)]) == 0
    return path


@pytest.fixture(scope="session")
def surveyed_recording():
    """Configuration B with known poses, 30 frames of centroids (seed 2); the
    truth keeps only the surveyed poses (no trajectory)."""
    import dataclasses

    import numpy as np

    from mmsnap_graph.data.recording import Truth
    from mmsnap_graph.sim import SimulationOptions, simulate_recording

    rec = simulate_recording("B", "random", SimulationOptions(physics=None, known_poses=True),
                             levels=("centroids",), n_frames=30, seed=2)
    truth = Truth(frame=np.zeros(0, np.int64), target_id=np.zeros(0, np.int64),
                  state=np.zeros((0, 4)), node_poses=rec.truth.node_poses)
    return dataclasses.replace(rec, truth=truth)


@pytest.fixture(scope="session")
def fused_b_file(tmp_path_factory):
    """Path of a recording made by the CLI: configuration B, 120 frames of
    centroids (clean model, seed 2), calibrated and fused. Shared: read it,
    or copy it before changing it."""
    from mmsnap_graph.app.cli import main

    path = tmp_path_factory.mktemp("fused_b") / "rec.h5"
    assert main(["simulate", "-c", "B", "-t", "random", "-l", "centroids", "--model", "clean",
                 "-n", "120", "--seed", "2", "-o", str(path)]) == 0
    assert main(["calibrate", str(path)]) == 0
    assert main(["fuse", str(path)]) == 0
    return path
