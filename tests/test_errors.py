"""The project's exception hierarchy (mmsnap_graph.errors): one base class,
and each error also the matching built-in."""

from __future__ import annotations

import numpy as np
import pytest

import mmsnap_graph
from mmsnap_graph import errors
from mmsnap_graph.data.recording import Detections


@pytest.mark.parametrize("name", [n for n in errors.__all__
                                  if n not in ("MmsnapError", "MmsnapWarning")])
def test_every_error_is_an_mmsnap_error_and_a_value_error(name):
    cls = getattr(errors, name)
    assert issubclass(cls, errors.MmsnapError)
    assert issubclass(cls, ValueError), cls.__mro__
    with pytest.raises(errors.MmsnapError):
        raise cls("x", step="process") if cls is errors.MissingStepError else cls("x")


def test_a_missing_step_names_the_command_and_what_is_missing():
    err = errors.MissingStepError("no centroids: run mmsnap process", step="process",
                                  what="no centroids")
    assert isinstance(err, errors.CalibrationError)
    assert (err.step, err.what, str(err)) == ("process", "no centroids",
                                              "no centroids: run mmsnap process")
    assert errors.MissingStepError("no poses", step="calibrate").what == "no poses"


def test_the_top_level_package_exports_the_same_classes():
    for name in ("MmsnapError", "ValidationError", "FileFormatError", "CalibrationError"):
        assert getattr(mmsnap_graph, name) is getattr(errors, name)


def test_a_bad_argument_is_caught_by_except_value_error():
    """A caller that knows only the built-ins still catches the project's
    validation errors."""
    with pytest.raises(ValueError, match="range_m") as info:
        Detections(frame=[0, 1], range_m=[1.0, np.nan], omega_rad=[0.0, 0.1],
                   doppler_mps=[0.0, 0.1])
    assert isinstance(info.value, errors.ValidationError)


def test_the_warning_is_a_user_warning_not_an_error():
    assert issubclass(errors.MmsnapWarning, UserWarning)
    assert not issubclass(errors.MmsnapWarning, errors.MmsnapError)
    with pytest.warns(errors.MmsnapWarning, match="radians"):
        import warnings
        warnings.warn("radians?", errors.MmsnapWarning)
