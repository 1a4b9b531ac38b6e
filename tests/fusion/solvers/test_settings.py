"""The solvers' contract: one name per solver, one set of Levenberg-Marquardt
settings (validated once, mirrored into GTSAM's parameters)."""

from __future__ import annotations

import dataclasses

import pytest

from mmsnap_graph.errors import ValidationError
from mmsnap_graph.fusion.solvers.settings import (
    LM_SETTINGS,
    SOLVERS,
    LevenbergMarquardtSettings,
    check_solver,
)


def test_one_name_per_solver():
    assert SOLVERS == ("gtsam", "vectorized", "scalar")
    for name in SOLVERS:
        assert check_solver(name) == name


@pytest.mark.parametrize("old, new", [("batch", "vectorized"), ("numpy", "scalar")])
def test_a_former_solver_name_is_refused_naming_the_new_one(old, new):
    with pytest.raises(ValidationError, match=f"'{old}' is now called '{new}'"):
        check_solver(old)
    with pytest.raises(ValidationError, match="options.solver must be 'vectorized' or 'gtsam'"):
        check_solver("scalar", ("vectorized", "gtsam"), what="options.solver")


@pytest.mark.parametrize("kwargs, match", [
    ({"lambda_initial": 0.0}, "lambda_initial must be a positive finite number"),
    ({"lambda_factor": 1.0}, "lambda_factor must be a finite number > 1"),
    ({"lambda_min": -1.0}, "lambda_min must be a finite number >= 0"),
    ({"lambda_min": 1e-3}, "need lambda_min <= lambda_initial < lambda_max"),
    ({"lambda_max": 1e-6}, "need lambda_min <= lambda_initial < lambda_max"),
    ({"min_diagonal": 1e40}, "need min_diagonal <= max_diagonal"),
    ({"relative_tolerance": float("nan")}, "relative_tolerance must be a positive finite"),
    ({"max_iterations": 0}, "max_iterations must be an integer >= 1"),
    ({"max_steps": 2.0}, "max_steps must be an integer >= 1"),
])
def test_settings_are_validated_once(kwargs, match):
    with pytest.raises(ValidationError, match=match):
        LevenbergMarquardtSettings(**kwargs)


def test_nielsens_update_is_bounded():
    assert LM_SETTINGS.damping_update(1.0) == pytest.approx(1.0 / 3.0)
    assert LM_SETTINGS.damping_update(0.5) == pytest.approx(1.0)
    assert LM_SETTINGS.damping_update(1e300) == pytest.approx(1.0 / 3.0)  # no OverflowError


def test_gtsam_parameters_mirror_the_settings():
    pytest.importorskip("gtsam")
    from mmsnap_graph.fusion.solvers.gtsam_graph import lm_params

    s = LevenbergMarquardtSettings(lambda_initial=1e-4, lambda_factor=5.0, lambda_min=1e-9,
                                   lambda_max=1e6, relative_tolerance=1e-12,
                                   absolute_tolerance=1e-13, max_iterations=77)
    p = lm_params(s)
    assert (p.getlambdaInitial(), p.getlambdaFactor(), p.getlambdaLowerBound(),
            p.getlambdaUpperBound()) == (1e-4, 5.0, 1e-9, 1e6)
    assert (p.getRelativeErrorTol(), p.getAbsoluteErrorTol(), p.getMaxIterations()) == \
        (1e-12, 1e-13, 77)
    assert p.getDiagonalDamping() and not p.getUseFixedLambdaFactor()
    # what GTSAM's Python wrapper cannot set is refused, not silently ignored
    with pytest.raises(ValidationError, match="min_diagonal"):
        lm_params(dataclasses.replace(s, min_diagonal=1e-3))
