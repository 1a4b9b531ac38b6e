"""The demo's sample recordings (mmsnap_graph.app.demo.samples): find and cut."""

from __future__ import annotations

import pytest

from mmsnap_graph.errors import ValidationError
from mmsnap_graph.app import demo

from _shared import DATA


def test_truncate_recording_keeps_the_first_frames():
    rec = demo.simulate_run("A", "random", n_frames=40, seed=1)
    cut = demo.truncate_recording(rec, 25)
    assert cut.truth.frame.max() == 24
    for node in cut.nodes.values():
        assert node.point_cloud.frame.max() <= 24
        assert node.cube is None


def test_find_sample_data(tmp_path, monkeypatch):
    with pytest.raises(ValidationError, match="does not exist"):
        demo.find_sample_data(tmp_path / "nope")
    assert demo.find_sample_data(tmp_path) == tmp_path
    if not demo.sample_path(DATA, "C", "straight").is_file():
        pytest.skip("sample recordings missing (python data/make_samples.py)")
    # From a folder without data/: the source checkout's data/ next to the package.
    monkeypatch.chdir(tmp_path)
    assert demo.find_sample_data() == DATA
    # A working directory with data/ of its own comes first.
    mine = tmp_path / "data"
    mine.mkdir()
    demo.sample_path(mine, "C", "straight").write_bytes(b"")
    assert demo.find_sample_data() == mine
