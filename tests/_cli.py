"""Running the ``mmsnap`` command line inside a test."""

from __future__ import annotations

from mmsnap_graph.app.cli import main

__all__ = ["run_cli", "error_line"]


def run_cli(capsys, *argv):
    """``(exit code, stdout, stderr)`` of ``mmsnap ARGV`` (argparse's own
    exits included); the arguments may be paths or numbers."""
    try:
        code = main([str(a) for a in argv])
    except SystemExit as exc:  # argparse: a value of the wrong type or choice
        code = exc.code
    out = capsys.readouterr()
    return code, out.out, out.err


def error_line(err: str) -> str:
    """The one error line (argparse prints its usage before it)."""
    lines = [ln for ln in err.strip().splitlines() if ": error: " in ln]
    assert len(lines) == 1 and lines[0] == err.strip().splitlines()[-1], err
    return lines[0]
