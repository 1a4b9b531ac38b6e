"""The project's one exception hierarchy.

Every error also subclasses the matching built-in, so ``except ValueError``
keeps working for callers that do not know this package.

A message speaks plain numbers: numpy's reprs that a ``{value!r}`` puts in
it (``np.float64(0.5)``, ``np.True_``, ``array([0., 0.])``) read as the
numbers and lists they hold (``0.5``, ``True``, ``[0., 0.]``), in every error
and warning of this module (:func:`plain_numbers`).
"""

from __future__ import annotations

import re

__all__ = [
    "MmsnapError",
    "ValidationError",
    "GeometryError",
    "ConfigurationError",
    "FileFormatError",
    "CalibrationError",
    "MissingStepError",
    "DeviceError",
    "MmsnapWarning",
    "plain_numbers",
]

#: numpy scalar reprs: np.float64(0.5), np.int64(3), np.str_('S1'), ...
_NP_SCALAR = re.compile(r"\bnp\.(?:u?int|float|complex|longdouble|clongdouble|half|single|double|"
                        r"str_|bytes_|datetime64|timedelta64)\d*\(((?:[^()]|\([^()]*\))*)\)")
_NP_BOOL = re.compile(r"\bnp\.(True|False)_")
#: numpy array reprs: array([0., 0.]), array([1, 2], dtype=int32), array(3.)
_NP_ARRAY = re.compile(r"\barray\(((?:\[|-?\d|-?\.\d|-?nan|-?inf|'|True|False)"
                       r"(?:[^()]|\([^()]*\))*?)(?:,\s*dtype=[^()]*?)?\)")


def plain_numbers(text: str) -> str:
    """``text`` with numpy's scalar and array reprs replaced by the numbers
    and lists they hold (``np.float64(0.5)`` -> ``0.5``, ``array([[ 1.,  2.],
    [ 3., nan]])`` -> ``[[1., 2.], [3., nan]]``): what a user reads."""
    if "np." not in text and "array(" not in text:
        return text
    text = _NP_BOOL.sub(r"\1", _NP_SCALAR.sub(r"\1", text))
    return _NP_ARRAY.sub(lambda m: re.sub(r"\s*,\s*", ", ",
                                          re.sub(r"\[\s+", "[", " ".join(m.group(1).split()))),
                         text)


def _plain_args(args: tuple) -> tuple:
    return (plain_numbers(args[0]),) + args[1:] if args and isinstance(args[0], str) else args


class MmsnapError(Exception):
    """Base class of every error raised by mmsnap_graph (its message in
    plain numbers: module docstring)."""

    def __init__(self, *args) -> None:
        super().__init__(*_plain_args(args))


class ValidationError(MmsnapError, ValueError):
    """An argument has the wrong shape, dtype, or a non-finite or out-of-range value."""


class GeometryError(MmsnapError, ValueError):
    """The geometry is degenerate in a way no estimator can handle (e.g. a
    target at a node's position)."""


class ConfigurationError(MmsnapError, ValueError):
    """A radar or processing configuration is inconsistent (e.g. a cube whose
    shape disagrees with its chirp configuration)."""


class FileFormatError(MmsnapError, ValueError):
    """A recording or capture file is missing a field, truncated or malformed."""


class CalibrationError(MmsnapError, ValueError):
    """Calibration input cannot determine a pose (too few common frames, no
    common target, a standing target)."""


class MissingStepError(CalibrationError):
    """The recording lacks what an earlier step makes: tracks or centroids
    (``mmsnap process``), node poses (``mmsnap calibrate``). ``step`` names
    that command and ``what`` says what is missing without the library's
    advice, so the command line can say which command to run."""

    def __init__(self, message: str, *, step: str, what: str | None = None) -> None:
        super().__init__(message)
        self.step = step
        self.what = plain_numbers(message if what is None else what)


class DeviceError(MmsnapError, ValueError):
    """A board or its serial port does not answer as it should: a port that
    cannot be opened or found, a CLI reply that is not the board's, a data
    port that stays silent."""


class MmsnapWarning(UserWarning):
    """Input that is probably a mistake but may be meant (radians given where
    degrees are asked, angles all within a degree or two): issued with
    :func:`warnings.warn`; ``mmsnap`` prints it as ``mmsnap VERB: warning: ...``
    and goes on. ``warnings.simplefilter("error", MmsnapWarning)`` makes each
    an error. Its message is in plain numbers (module docstring)."""

    def __init__(self, *args) -> None:
        super().__init__(*_plain_args(args))
