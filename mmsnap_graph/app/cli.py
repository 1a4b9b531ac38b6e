"""The ``mmsnap`` command line: one sub-command per module in
:mod:`mmsnap_graph.app.commands` (also ``python -m mmsnap_graph``).

Each command module defines ``register(subparsers)`` that adds its parser and
sets ``func`` to a function ``run(args) -> int``. Degrees appear only here and
in reports; the library speaks radians.

Exit codes (:data:`EXIT_OK`, :data:`EXIT_FAILURE`, :data:`EXIT_USAGE`):
0 the command did its work; 1 it ran, but the data or an estimation failed
(nothing processed, a calibration incomplete, a recording of ``batch``
failed, a paper check of ``demo`` does not hold, a file could not be
written); 2 it could not run on what it was given: a bad option (argparse),
or an input file that is missing, damaged or inconsistent (the project's
errors, :class:`~mmsnap_graph.errors.MmsnapError`). Errors are one line on
stderr, ``mmsnap VERB: error: ...``, naming the file. ``-v``/``-q`` set the
level of the ``mmsnap_graph`` logger (warnings by default).
"""

from __future__ import annotations

import argparse
import importlib
import importlib.metadata
import logging
import sys

from ..errors import MmsnapError

#: Sub-command modules under mmsnap_graph.app.commands, in help order.
COMMANDS: list[str] = ["process", "simulate", "calibrate", "fuse", "demo", "evaluate", "import_", "batch", "replay", "monitor", "noise"]

EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_USAGE = 2


def package_version() -> str:
    """The installed distribution's version (``mmsnap_graph.__version__``)."""
    try:
        return importlib.metadata.version("mmsnap_graph")
    except importlib.metadata.PackageNotFoundError:  # run from a source tree
        return "unknown"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="mmsnap",
        description="Self-calibration and Bayesian one-shot fusion for mmWave radar networks.",
        epilog="Exit codes: 0 ok, 1 data or estimation failure, 2 bad option or input file.",
    )
    parser.add_argument("--version", action="version", version=f"mmsnap {package_version()}")
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


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    configure_logging(args.verbose, args.quiet)
    try:
        return int(args.func(args) or 0)
    except MmsnapError as exc:
        print(f"mmsnap {args.command}: error: {_one_line(exc)}", file=sys.stderr)
        return EXIT_USAGE
    except OSError as exc:  # the environment: permissions, a full disk, ...
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"mmsnap {args.command}: error: {where}{_one_line(exc.strerror or exc)}",
              file=sys.stderr)
        return EXIT_FAILURE
    except KeyboardInterrupt:
        print(f"mmsnap {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
