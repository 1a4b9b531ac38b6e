"""The argparse types the sub-commands share (mmsnap_graph/app/commands/arguments.py):
``NAME=VALUES`` options, a pose in degrees, the solver name, the sigmas'
plausibility limits."""

from __future__ import annotations

import argparse
import math

import pytest

from mmsnap_graph.app.commands.arguments import (
    SIGMA_LIMITS,
    check_sigmas,
    looks_like_radians,
    named_pose,
    named_values,
    solver_choice,
)
from mmsnap_graph.errors import MmsnapWarning, ValidationError


def test_named_values_splits_the_name_and_the_numbers():
    parse = named_values("HEIGHT_M,TILT_DEG", 2)
    assert parse("S2=1.2,15") == ("S2", [1.2, 15.0])
    assert parse("left=-0.5,1e-3") == ("left", [-0.5, 0.001])
    # one string value: no numbers parsed
    assert named_values("FILE", None)("S1=logs/a=b.bin") == ("S1", "logs/a=b.bin")


@pytest.mark.parametrize("text", ["S2", "=1,2", "S2=", "S2=1", "S2=1,2,3", "S2=1,x", "S2:1,2"])
def test_named_values_refuses_other_shapes_naming_the_expected_one(text):
    with pytest.raises(argparse.ArgumentTypeError, match=r"must look like NAME=HEIGHT_M,TILT_DEG"):
        named_values("HEIGHT_M,TILT_DEG", 2)(text)


def test_named_pose_reads_degrees_and_gives_radians():
    name, (x, y, phi) = named_pose("S2=0,7,180")
    assert (name, x, y) == ("S2", 0.0, 7.0)
    assert phi == pytest.approx(math.pi, abs=1e-15)
    assert named_pose("S3=-1.5,2,-90")[1][2] == pytest.approx(-math.pi / 2, abs=1e-15)
    with pytest.raises(argparse.ArgumentTypeError, match=r"X_M,Y_M,PHI_DEG \(e.g. S2=0,7,180\)"):
        named_pose("S2=0,7")


def test_solver_choice_keeps_the_allowed_names_and_names_the_replacement_of_an_old_one():
    parse = solver_choice(("gtsam", "vectorized"))
    assert parse("gtsam") == "gtsam" and parse("vectorized") == "vectorized"
    assert parse.__name__ == "solver"  # argparse's "invalid solver value" message
    with pytest.raises(argparse.ArgumentTypeError, match=r"'batch' is now called 'vectorized'"):
        parse("batch")
    with pytest.raises(argparse.ArgumentTypeError, match=r"--solver must be 'gtsam' or "
                                                           r"'vectorized', got 'scalar'"):
        parse("scalar")


def test_check_sigmas_accepts_plausible_values_up_to_each_limit():
    check_sigmas((0.05, 0.1, 0.2))
    check_sigmas([limit for _, limit, _ in SIGMA_LIMITS])  # the limits themselves pass
    assert [name for name, _, _ in SIGMA_LIMITS] == ["range_m", "omega_rad", "doppler_mps"]
    assert SIGMA_LIMITS[1][1] == math.pi  # |omega| = |pi sin(theta)| <= pi


@pytest.mark.parametrize("values, match", [
    ((0.0, 0.1, 0.2), r"--sigmas: range_m must be finite and > 0, got 0.0"),
    ((0.05, float("nan"), 0.2), r"omega_rad must be finite and > 0"),
    ((0.05, 0.1, -1.0), r"doppler_mps must be finite and > 0"),
    ((5.0 * 100, 0.1, 0.2), r"range_m=500 is more than 10.*centimetres or millimetres typed"),
    ((0.05, 5.0, 0.2), r"omega_rad=5 is more than 3.142.*degrees typed"),
    ((0.05, 0.1, 60.0), r"doppler_mps=60 is more than 50.*km/h or cm/s typed"),
])
def test_check_sigmas_names_the_component_and_the_likely_unit_mistake(values, match):
    with pytest.raises(ValidationError, match=match):
        check_sigmas(values)


@pytest.mark.parametrize("text, radians", [
    ("1.5708", True), ("3.14", True), ("-1.571", True), ("0.785", True), ("6.28", True),
    ("0.087", True), ("0.26", True), ("90", False), ("180", False), ("0", False), ("5", False),
    ("1.5", False), ("2.5", False), ("-45", False), ("12.5", False), ("7.854", False),
])
def test_radians_where_degrees_are_asked(text, radians):
    assert looks_like_radians(float(text), text) is radians


def test_a_heading_in_radians_warns_and_is_kept():
    """--room-pose S2=1.7,1.65,1.5708 was read as 1.57 degrees without a word
    (the real recording then calibrated S2 at -0.28 deg, 'ok')."""
    with pytest.warns(MmsnapWarning, match=r"'S2=1.7,1.65,1.5708': PHI_DEG=1.5708 looks like "
                                           r"radians \(1.5708 rad = 90 deg\); this option "
                                           r"takes degrees"):
        assert named_values("X_M,Y_M,PHI_DEG", 3, (2,))("S2=1.7,1.65,1.5708") == \
            ("S2", [1.7, 1.65, 1.5708])
    with pytest.warns(MmsnapWarning, match="PHI_DEG=3.1416 looks like radians"):
        named_pose("S2=0,7,3.1416")
    with pytest.warns(MmsnapWarning, match="TILT_DEG=0.087 looks like radians"):
        named_values("HEIGHT_M,TILT_DEG", 2, (1,))("S1=0.8,0.087")
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("error", MmsnapWarning)
        named_pose("S2=1.7,1.65,90")
        named_values("X_M,Y_M,PHI_DEG", 3, (2,))("S2=1.571,1.65,90")   # metres are not checked
