"""The ``mmsnap`` command line: one sub-command per module in
:mod:`mmsnap_graph.app.commands` (also ``python -m mmsnap_graph``).

Each command module defines ``register(subparsers)`` that adds its parser and
sets ``func`` to a function ``run(args) -> int``. Degrees appear only here and
in reports; the library speaks radians.

Exit codes (:data:`EXIT_OK`, :data:`EXIT_FAILURE`, :data:`EXIT_USAGE`):

- 0 the command did its work;
- 1 the data or an estimation failed: an input file that is missing,
  unreadable, damaged or inconsistent (:data:`DATA_ERRORS`: a
  :class:`~mmsnap_graph.errors.FileFormatError`,
  :class:`~mmsnap_graph.errors.CalibrationError` or
  :class:`~mmsnap_graph.errors.GeometryError`, or an ``OSError``), nothing
  processed, a calibration incomplete, a recording of ``batch`` failed, a
  paper check of ``demo`` does not hold, a file could not be written;
- 2 usage: a bad option (argparse) or option value
  (:data:`USAGE_ERRORS`: a :class:`~mmsnap_graph.errors.ValidationError` or
  :class:`~mmsnap_graph.errors.ConfigurationError` raised for an option),
  including an output path that is a folder, a device node, a FIFO or a
  socket, lies in a missing folder, is one of the command's input files, or
  exists without ``--overwrite``
  (checked before the command runs: :mod:`mmsnap_graph.app.commands.file_rules`);
- 141 standard output was closed by its reader (``mmsnap replay ... | head``);
  nothing is printed.

Errors are one line on stderr, ``mmsnap VERB: error: ...``; an error of an
input file names the file. Input that is probably a mistake but may be meant
(:class:`~mmsnap_graph.errors.MmsnapWarning`) is one line ``mmsnap VERB:
warning: ...``, and the command goes on. ``-v``/``-q`` set the level of the
``mmsnap_graph`` logger (warnings by default).
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import re
import sys
import warnings
from pathlib import Path

from .commands.file_rules import check_files
from ..errors import (
    CalibrationError,
    ConfigurationError,
    DeviceError,
    FileFormatError,
    GeometryError,
    MissingStepError,
    MmsnapError,
    MmsnapWarning,
    ValidationError,
)

#: Sub-command modules under mmsnap_graph.app.commands, in help order.
COMMANDS: list[str] = ["process", "simulate", "calibrate", "fuse", "demo", "evaluate",
                       "files.import_", "batch", "replay", "monitor", "noise", "files.info",
                       "files.export", "files.plot", "boards.record", "boards.live"]

EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_USAGE = 2
#: The reader of standard output went away (``mmsnap replay ... | head``):
#: no message, the shell's code for a write to a closed pipe (128 + SIGPIPE).
EXIT_BROKEN_PIPE = 141

#: The option giving node poses in place of the recording's, per command.
STEP_OPTIONS = {"fuse": "--calibration", "replay": "--calibration", "noise": "--calibration",
                "evaluate": "--calibration", "monitor": "--poses"}

#: Errors of the data (an input file, an estimation): exit 1.
DATA_ERRORS = (FileFormatError, CalibrationError, GeometryError, DeviceError)
#: Errors of an option value: exit 2.
USAGE_ERRORS = (ValidationError, ConfigurationError)

def package_version() -> str:
    """The installed distribution's version (``mmsnap_graph.__version__``)."""
    import importlib.metadata  # here: it costs a tenth of a second, --help does without

    try:
        return importlib.metadata.version("mmsnap_graph")
    except importlib.metadata.PackageNotFoundError:  # run from a source tree
        return "unknown"


class _VersionAction(argparse.Action):
    """``--version``: the version is looked up when asked for, not each time
    the parser is built."""

    def __call__(self, parser, namespace, values, option_string=None):
        print(f"mmsnap {package_version()}")  # on stdout, as argparse's own version action
        parser.exit()


#: A value that starts with a minus sign and is a number or a comma list of
#: numbers (``-0.05``, ``-2,5,-1,3``, ``-1e-3,2``): a value, not an option.
NEGATIVE_NUMBERS = re.compile(r"^-(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
                              r"(?:\s*,\s*[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)*$")


class ArgumentParser(argparse.ArgumentParser):
    """argparse's parser, taking a value that starts with a minus sign for a
    value when it is a number or a comma list of numbers
    (:data:`NEGATIVE_NUMBERS`): ``--bounds -2,5,-1,3``, ``--height-band
    -0.1,2``, ``--range-offset -0.05,0.02`` (argparse alone accepts ``-0.05``
    but takes ``-2,5,...`` for an unknown option and asks for ``=``). No
    option of mmsnap looks like a negative number, so none is shadowed. Its
    sub-command parsers are of this class too."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        # argparse's own test of "a negative number" (a private attribute,
        # the same in Python 3.11-3.13; tests/app/test_cli.py checks it is used)
        self._negative_number_matcher = NEGATIVE_NUMBERS


def build_parser() -> argparse.ArgumentParser:
    parser = ArgumentParser(
        prog="mmsnap",
        description="Self-calibration and Bayesian one-shot fusion for mmWave radar networks.",
        epilog="Exit codes: 0 ok, 1 data or estimation failure (a bad input file included), "
               "2 usage (a bad option or option value).",
    )
    parser.add_argument("--version", action=_VersionAction, nargs=0,
                        help="show the program's version number and exit")
    parser.add_argument("-v", "--verbose", action="count", default=0,
                        help="more log messages (-v info, -vv debug)")
    parser.add_argument("-q", "--quiet", action="count", default=0,
                        help="fewer log messages (-q errors only)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in COMMANDS:
        importlib.import_module(f"mmsnap_graph.app.commands.{name}").register(sub)
    return parser


class _StderrHandler(logging.StreamHandler):
    """Writes to the current ``sys.stderr`` (which tests and callers may swap)."""

    def emit(self, record: logging.LogRecord) -> None:
        self.stream = sys.stderr
        super().emit(record)


def configure_logging(verbose: int, quiet: int) -> None:
    """Level of the ``mmsnap_graph`` logger: WARNING, raised by ``-q``,
    lowered by ``-v``; messages go to stderr as ``mmsnap: LEVEL: text``."""
    level = min(max(logging.WARNING + 10 * (quiet - verbose), logging.DEBUG), logging.CRITICAL)
    log = logging.getLogger("mmsnap_graph")
    log.setLevel(level)
    if not any(isinstance(h, _StderrHandler) for h in log.handlers):
        handler = _StderrHandler()
        handler.setFormatter(logging.Formatter("mmsnap: %(levelname)s: %(message)s"))
        log.addHandler(handler)


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def input_files(args: argparse.Namespace) -> list[str]:
    """The input files named on the command line (for error messages)."""
    names = [getattr(args, "recording", None), getattr(args, "calibration", None)]
    return [str(n) for n in names if isinstance(n, str)]


def _data_error_text(exc: BaseException, args: argparse.Namespace) -> str:
    """The one-line message of a data error, prefixed with the input file
    when there is exactly one and the message does not name it."""
    text = _one_line(exc)
    recording = getattr(args, "recording", None)
    if isinstance(exc, MissingStepError) and exc.step != args.command and recording:
        # Say which command makes what is missing (and the option doing without it).
        text = f"{_one_line(exc.what)}: run `mmsnap {exc.step} {recording}` first"
        if exc.step == "calibrate" and args.command in STEP_OPTIONS:
            text += f" (or give {STEP_OPTIONS[args.command]} CALIBRATION_JSON)"
    files = input_files(args)
    if files and not any(f in text or Path(f).name in text for f in files):
        text = f"{files[0]}: {text}"
    return text


def _silence_stdout() -> None:
    """Point stdout at /dev/null: its reader is gone, and the interpreter's
    last flush would report the broken pipe again."""
    try:
        fd = sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):  # not a real file (captured)
        return
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, fd)
    os.close(devnull)


def main(argv: list[str] | None = None) -> int:
    """Run ``mmsnap`` with ``argv``; the exit code (module docstring)."""
    parser = build_parser()
    with warnings.catch_warnings(record=True) as parsing:   # an option's value (degrees)
        warnings.simplefilter("always", MmsnapWarning)
        args = parser.parse_args(argv)
    configure_logging(args.verbose, args.quiet)
    prefix = f"mmsnap {args.command}: error:"
    with warnings.catch_warnings():
        warnings.simplefilter("always", MmsnapWarning)
        default_show = warnings.showwarning

        def show(message, category, filename, lineno, file=None, line=None):
            if not issubclass(category, MmsnapWarning):
                return default_show(message, category, filename, lineno, file, line)
            print(f"mmsnap {args.command}: warning: {_one_line(message)}", file=sys.stderr)

        warnings.showwarning = show
        for w in parsing:
            show(w.message, w.category, w.filename, w.lineno)
        return _run(args, prefix)


def _run(args: argparse.Namespace, prefix: str) -> int:
    """``args.func(args)``, its errors as one line and an exit code."""
    try:
        check_files(args)
        return int(args.func(args) or 0)
    except DATA_ERRORS as exc:
        print(f"{prefix} {_data_error_text(exc, args)}", file=sys.stderr)
        return EXIT_FAILURE
    except MmsnapError as exc:  # USAGE_ERRORS and any other option check
        print(f"{prefix} {_one_line(exc)}", file=sys.stderr)
        return EXIT_USAGE
    except BrokenPipeError:  # `mmsnap replay ... | head`: the reader has all it wants
        _silence_stdout()
        return EXIT_BROKEN_PIPE
    except OSError as exc:  # an input file, or the environment: permissions, a full disk, ...
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"{prefix} {where}{_one_line(exc.strerror or exc)}", file=sys.stderr)
        return EXIT_FAILURE
    except KeyboardInterrupt:
        print(f"mmsnap {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
