"""The project's exception hierarchy (mmsnap_graph.errors): one base class,
and each error also the matching built-in."""

from __future__ import annotations

import numpy as np
import pytest

import mmsnap_graph
from mmsnap_graph import errors
from mmsnap_graph.data.recording import Detections


@pytest.mark.parametrize("name", [n for n in errors.__all__
                                  if n not in ("MmsnapError", "MmsnapWarning", "plain_numbers")])
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


@pytest.mark.parametrize("value, plain", [
    (np.float64(0.5), "0.5"), (np.int64(-7), "-7"), (np.True_, "True"), (np.str_("S1"), "'S1'"),
    (np.array([np.nan, 0.0]), "[nan, 0.]"), (np.array([1, 2], dtype=np.int32), "[1, 2]"),
    (np.array([[1.0, 2.0], [3.0, np.nan]]), "[[1., 2.], [3., nan]]"), (np.array(3.0), "3."),
    ((np.float64(np.nan), np.int64(3)), "(nan, 3)"), ({"a": np.float32(1.5)}, "{'a': 1.5}"),
])
def test_a_message_speaks_plain_numbers_not_numpy_reprs(value, plain):
    """Before: `{value!r}` of a numpy value put np.float64(0.5) or
    array([nan,  0.]) into messages (issue 29's small ones)."""
    assert str(errors.ValidationError(f"x={value!r} is bad")) == f"x={plain} is bad"
    assert str(errors.MmsnapWarning(f"x={value!r}")) == f"x={plain}"
    err = errors.MissingStepError(f"x={value!r}", step="process")
    assert (str(err), err.what) == (f"x={plain}", f"x={plain}")
    assert errors.plain_numbers("np.float64 is a type; array(s) are not") == \
        "np.float64 is a type; array(s) are not"


def _public_records():
    import dataclasses
    import importlib
    import inspect
    import pkgutil

    seen = {}
    for info in pkgutil.walk_packages(mmsnap_graph.__path__, "mmsnap_graph."):
        if ".view" in info.name or ".live" in info.name:  # optional extras
            continue
        try:
            module = importlib.import_module(info.name)
        except ImportError:
            continue
        for name in getattr(module, "__all__", ()):
            cls = getattr(module, name, None)
            if inspect.isclass(cls) and dataclasses.is_dataclass(cls):
                seen.setdefault(f"{cls.__module__}.{cls.__qualname__}", cls)
    return seen


def test_no_option_record_puts_a_numpy_repr_into_its_error():
    """Every public option record (a dataclass in a module's __all__ that
    builds with its defaults), each field given numpy values it refuses: the
    error names plain numbers. Before: 629 of the 752 refusals of the 36
    records held np.float64(...) or array(...) (JointOptions, RealPhysics,
    EkfConfig, DemoConfig, ...)."""
    import dataclasses
    import re
    import warnings

    leak = re.compile(r"np\.\w+\(|np\.(True|False)_|array\(")
    values = (np.float64(np.nan), np.int64(-7), np.array([np.nan, 0.0]),
              (np.float64(np.nan), np.float64(1.0)))
    records, refused, leaks = 0, 0, []
    for name, cls in sorted(_public_records().items()):
        try:
            base = cls()
        except Exception:  # a record without defaults: not an option record
            continue
        records += 1
        for field in (f for f in dataclasses.fields(cls) if f.init):
            for value in values:
                try:
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore")
                        dataclasses.replace(base, **{field.name: value})
                except errors.MmsnapError as exc:
                    refused += 1
                    if leak.search(str(exc)):
                        leaks.append((name, field.name, str(exc)))
                except Exception:  # noqa: BLE001 - other failures are not this test's
                    pass
    assert records > 30 and refused > 500, (records, refused)
    assert leaks == [], (len(leaks), records, refused, leaks[:3])
