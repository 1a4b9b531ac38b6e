"""The demo's orchestrator (mmsnap_graph.app.demo.run): its options, its handling of a
failed calibration and, on the sample recordings cut to 300 frames, the paper's
qualitative results (the full demo, 600 frames x 6 runs, is not run here)."""

from __future__ import annotations

import numpy as np
import pytest

from mmsnap_graph.errors import CalibrationError, ValidationError
from mmsnap_graph.app import demo
from mmsnap_graph.app.report import qualitative_checks


@pytest.mark.slow
def test_paper_claims_hold_on_the_sample_recordings(demo_on_samples):
    res = demo_on_samples
    assert not res.failures
    assert set(res.fusions) == {(c, t) for c in "ABC" for t in ("straight", "random")}
    checks = {c.claim: c for c in qualitative_checks(res)}
    assert len(checks) == 3
    for c in checks.values():
        assert c.holds, f"{c.claim}: {c.detail}"


@pytest.mark.slow
def test_configuration_b_best_and_c_worst_for_position(demo_on_samples):
    pos = {c: np.mean([demo_on_samples.fusions[(c, t)].vs_truth["bayes"].position_rmse_m
                       for t in ("straight", "random")]) for c in "ABC"}
    assert pos["B"] < pos["A"] < pos["C"]


@pytest.mark.slow
def test_ml_velocity_fails_in_c_while_bayesian_holds(demo_on_samples):
    for t in ("straight", "random"):
        f = demo_on_samples.fusions[("C", t)]
        assert f.vs_truth["ml"].velocity_rmse_mps > 2.5 * f.vs_truth["bayes"].velocity_rmse_mps
        # Frames on the line through the radars are there (the cause).
        assert np.mean(f.degeneracy > 100) > 0.05
    for c in "AB":
        for t in ("straight", "random"):
            v = demo_on_samples.fusions[(c, t)].vs_truth
            assert v["ml"].velocity_rmse_mps == pytest.approx(v["bayes"].velocity_rmse_mps, rel=0.1)


@pytest.mark.slow
def test_refined_calibration_at_least_as_good_as_closed_form(demo_on_samples):
    for cal in demo_on_samples.calibrations.values():
        assert cal.success, cal.message
        assert cal.refined_mapping_error_m <= cal.closed_form_mapping_error_m
        # The closed form minimizes exactly the track RMSE (paper eq. 14):
        # the refined pose cannot beat it on that score.
        assert cal.refined_rmse_m >= cal.closed_form_rmse_m - 1e-12


@pytest.mark.slow
def test_one_shot_is_compared_on_common_frames(demo_on_samples):
    f = demo_on_samples.fusions[("B", "random")]
    assert f.calibrated_on == "straight"
    k = f.frame.size
    assert k > 250
    for name in ("truth", "bayes", "ml", "track_fusion", "central", "ekf_s1", "ekf_s2"):
        assert getattr(f, name).shape == (k, 4)
    assert f.vs_truth["bayes"].n_frames == k
    assert f.measurements.shape == (k, 2, 3)
    # The benchmark itself tracks the truth closely in configuration B.
    assert f.vs_truth["track_fusion"].position_rmse_m < 0.1


def test_other_trajectory():
    assert demo.other_trajectory("straight", ("straight", "random")) == "random"
    assert demo.other_trajectory("random", ("straight", "random")) == "straight"
    assert demo.other_trajectory("random", ("random",)) == "random"


@pytest.mark.parametrize("kwargs, match", [
    (dict(configurations=("D",)), "configurations"),
    (dict(configurations=()), "configurations"),
    (dict(trajectories=("zigzag",)), "trajectories"),
    (dict(configurations=("A", "A")), "must not repeat"),
    (dict(n_frames=5), "n_frames"),
    (dict(cube_frames=-1), "cube_frames"),
    (dict(cube_configuration="E"), "cube_configuration"),
    (dict(max_lag_frames=-1), "max_lag_frames"),
])
def test_demo_config_rejects_bad_values(kwargs, match):
    with pytest.raises(ValidationError, match=match):
        demo.DemoConfig(**kwargs)


def test_demo_config_protocol():
    assert demo.DemoConfig().protocol == "cross"
    assert demo.DemoConfig(trajectories=("random",)).protocol == "same"
    assert demo.DemoConfig(configurations=("b",)).configurations == ("B",)


def test_a_failed_calibration_is_reported_and_the_other_run_not_fused(monkeypatch):
    real = demo.calibrate_run

    def failing(rec, *, configuration, trajectory, **kw):
        if trajectory == "straight":  # force the failure of one calibration
            raise CalibrationError("forced")
        return real(rec, configuration=configuration, trajectory=trajectory, **kw)

    monkeypatch.setattr(demo.run, "calibrate_run", failing)  # where run_demo looks it up
    res = demo.run_demo(demo.DemoConfig(configurations=("B",), n_frames=40, cube_frames=0))
    assert set(res.calibrations) == {("B", "random")}
    assert set(res.fusions) == {("B", "straight")}
    assert any("B/straight: calibration failed: forced" in f for f in res.failures)
    assert any("B/random: not fused (no calibration from straight)" in f for f in res.failures)
