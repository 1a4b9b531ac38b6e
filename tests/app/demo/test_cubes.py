"""A raw-cube stretch through the whole signal chain (mmsnap_graph.app.demo.cubes)."""

from __future__ import annotations

import pytest

from mmsnap_graph.sim import CLEAN
from mmsnap_graph.errors import ValidationError
from mmsnap_graph.app import demo


def test_cube_stretch_runs_the_whole_chain():
    from mmsnap_graph.sim import simulate_recording

    rec = simulate_recording("C", "straight", CLEAN, levels=("cube",), n_frames=6, seed=3)
    cs = demo.run_cube_stretch(rec, source="test", configuration="C")
    assert cs.n_frames == 6
    for name in ("S1", "S2"):
        assert cs.n_points[name] > 6
        assert cs.detection_rate[name] >= 5 / 6
        r = cs.centroid_rms[name]
        # Centroid errors of a few range / Doppler cells at most (3.5 cm, 0.18 m/s).
        assert r[0] < 0.15 and r[2] < 0.3 and r[1] < 0.3
    assert cs.fused_vs_truth is not None and cs.fused_vs_truth.position_rmse_m < 0.3
    with pytest.raises(ValidationError, match="raw cubes"):
        demo.run_cube_stretch(demo.simulate_run("C", "straight", n_frames=5, seed=0), source="x")
