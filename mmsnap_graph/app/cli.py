"""The ``mmsnap`` command line: one sub-command per module in
:mod:`mmsnap_graph.app.commands`.

Each command module defines ``register(subparsers)`` that adds its parser and
sets ``func`` to a function ``run(args) -> int``. Degrees appear only here and
in reports; the library speaks radians.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from ..errors import MmsnapError

#: Sub-command modules under mmsnap_graph.app.commands, in help order.
COMMANDS: list[str] = ["process", "simulate", "calibrate", "fuse", "demo", "evaluate", "import_", "batch", "replay"]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="mmsnap",
        description="Self-calibration and Bayesian one-shot fusion for mmWave radar networks.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in COMMANDS:
        importlib.import_module(f"mmsnap_graph.app.commands.{name}").register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except MmsnapError as exc:
        print(f"mmsnap {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
