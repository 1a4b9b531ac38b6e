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
