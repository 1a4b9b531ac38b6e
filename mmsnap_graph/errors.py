"""The project's one exception hierarchy.

Every error also subclasses the matching built-in, so ``except ValueError``
keeps working for callers that do not know this package.
"""

from __future__ import annotations

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
]


class MmsnapError(Exception):
    """Base class of every error raised by mmsnap_graph."""


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
        self.what = message if what is None else what


class DeviceError(MmsnapError, ValueError):
    """A board or its serial port does not answer as it should: a port that
    cannot be opened or found, a CLI reply that is not the board's, a data
    port that stays silent."""


class MmsnapWarning(UserWarning):
    """Input that is probably a mistake but may be meant (radians given where
    degrees are asked, angles all within a degree or two): issued with
    :func:`warnings.warn`; ``mmsnap`` prints it as ``mmsnap VERB: warning: ...``
    and goes on. ``warnings.simplefilter("error", MmsnapWarning)`` makes each
    an error."""
