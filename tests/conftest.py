"""Shared fixtures: small simulated recordings built once per test session.

The shared plain values (the paper's networks, sigmas, noise and prior, the
small radar configuration, the samples folder) are in ``_shared.py`` because
several are needed at parametrize time, where fixtures cannot be used.

The recordings are session-scoped and shared between modules: a test must not
change one in place (``Recording.with_node`` and ``dataclasses.replace`` give
changed copies).
"""

from __future__ import annotations

import pytest

from mmsnap_graph.sim import simulate_recording
from mmsnap_graph.sim import CLEAN, SimulationOptions

from _shared import NETWORK_3_OPEN, POSES_BC
from _fusion import config

#: Session fixtures that take long to build (the demo's six runs, about a
#: minute): under pytest-xdist every test that uses one goes to the same worker
#: (``--dist loadgroup``, the README's test command), which builds it once.
#: Files shared by the workers are built once per run with ``_once.built_once``.
ONE_WORKER_FIXTURES = ("demo_on_samples",)


@pytest.hookimpl(tryfirst=True)  # before xdist's own hook reads the groups
def pytest_collection_modifyitems(config, items):
    if not config.pluginmanager.hasplugin("xdist"):
        return
    for item in items:
        used = [name for name in ONE_WORKER_FIXTURES if name in item.fixturenames]
        if used:
            item.add_marker(pytest.mark.xdist_group(used[0]))


@pytest.fixture(scope="session")
def two_target_recordings():
    """Configurations A, B, C: two walking targets, 200 frames, known poses,
    10 % missed centroids (seed 11)."""
    return {
        net: simulate_recording(net, "random",
                                SimulationOptions(physics=None, n_targets=2, known_poses=True, centroid_p_miss=0.1),
                                levels=("centroids",), n_frames=200, seed=11)
        for net in "ABC"
    }


@pytest.fixture(scope="session")
def recording_b_point_cloud():
    """Configuration B, one random walker, centroids and point clouds, default
    length (seed 11)."""
    return simulate_recording("B", "random", CLEAN, levels=("centroids", "point_cloud"), seed=11)


@pytest.fixture(scope="session")
def recording_c_random():
    """Configuration C, one random walker, 300 frames of centroids, poses
    unknown (seed 3): enough for calibration."""
    return simulate_recording("C", "random", CLEAN, levels=["centroids"], n_frames=300, seed=3)


@pytest.fixture(scope="session")
def recording_c_straight():
    """Configuration C, a straight walk, 20 frames of centroids (seed 0)."""
    return simulate_recording("C", "straight", CLEAN, levels=("centroids",), n_frames=20, seed=0)


@pytest.fixture(scope="session")
def point_cloud_recording_3():
    """The network ``_shared.NETWORK_3_OPEN``, two walkers, 120 frames of point
    clouds at 20 fps, no radar physics (seed 4)."""
    return simulate_recording(NETWORK_3_OPEN, "random",
                              SimulationOptions(physics=None, n_targets=2, frame_period_s=0.05),
                              levels=("point_cloud",), n_frames=120, seed=4)


@pytest.fixture(scope="session")
def recording_bc_known_poses():
    """The three nodes ``_shared.POSES_BC`` (S1, S2, S3), one random walker, 40
    frames of centroids, poses known, no radar physics (seed 9)."""
    network = {"S1": POSES_BC[0], "S2": POSES_BC[1], "S3": POSES_BC[2]}
    return simulate_recording(network, "random", SimulationOptions(physics=None, known_poses=True),
                              levels=("centroids",), n_frames=40, seed=9)


@pytest.fixture(scope="session")
def recording_b_known_poses():
    """Configuration B, one random walker, 60 frames of centroids, poses
    known, no radar physics (seed 5)."""
    return simulate_recording("B", "random", SimulationOptions(physics=None, known_poses=True),
                              levels=("centroids",), n_frames=60, seed=5)


@pytest.fixture(scope="session")
def fused_b_map(recording_b_known_poses):
    """``recording_b_known_poses`` fused with the default MAP mode."""
    from mmsnap_graph.fusion.recording.sequence import fuse_recording
    return fuse_recording(recording_b_known_poses, config(), progress=False)


@pytest.fixture(scope="session")
def fused_b_ml(recording_b_known_poses):
    """``recording_b_known_poses`` fused in ML mode without a prior."""
    from mmsnap_graph.fusion.recording.sequence import fuse_recording
    return fuse_recording(recording_b_known_poses, config(mode="ml", prior=None), progress=False)


@pytest.fixture(scope="session")
def recording_b_file(tmp_path_factory):
    """Path of a small recording file made by the CLI (``mmsnap simulate
    --model clean -c B -t random -n 40 -l centroids --seed 5 --known-poses``):
    two nodes at known poses, centroids and the truth. Shared: read it, or
    copy it before changing it."""
    from mmsnap_graph.app.cli import main

    path = tmp_path_factory.mktemp("recording_b") / "good.h5"
    assert main(["simulate", "--model", "clean", "-c", "B", "-t", "random", "-n", "40", "-l",
                 "centroids", "--seed", "5", "--known-poses", "-o", str(path),
                 "--no-progress"]) == 0
    return path


@pytest.fixture(scope="session")
def recording_b_real_file(tmp_path_factory):
    """As :func:`recording_b_file` with the simulator's default, real physics
    (``mmsnap simulate -c B -t random -n 40 -l centroids --seed 5
    --known-poses``). Shared: read it, or copy it before changing it."""
    from mmsnap_graph.app.cli import main

    path = tmp_path_factory.mktemp("recording_b_real") / "rec.h5"
    assert main(["simulate", "-c", "B", "-t", "random", "-n", "40", "-l", "centroids",
                 "--seed", "5", "--known-poses", "-o", str(path), "--no-progress"]) == 0
    return path
