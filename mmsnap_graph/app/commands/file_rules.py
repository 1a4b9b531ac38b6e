"""The one rule of every verb's input and output files, checked before a
command runs (so nothing is touched when it refuses):

- an output file (``-o``, ``--json-out PATH``) must lie in
  an existing folder and not be a folder;
- an output that resolves to one of the command's input files (the same
  file through another name, a symlink or a hard link) is refused: writing
  it would destroy the input;
- an existing output is replaced only with ``--overwrite``, the files a
  verb writes beside its recording included (``mmsnap calibrate``'s
  ``REC.calibration.json``);
- an output that is (or, through a symlink, names) a device node, a FIFO
  or a socket is refused: writers replace regular files only
  (:mod:`mmsnap_graph._atomic`);
- an output folder (``mmsnap demo --out``, ``mmsnap batch --output-dir``)
  that exists and is not a folder (a file, a device, a FIFO, through a
  symlink too) is refused: its files are written inside it;
- an input file that exists but is not a regular file (a FIFO, a device, a
  socket) is refused: reading it would block for ever.

Output refusals are usage errors (:class:`~mmsnap_graph.errors.ValidationError`,
exit 2) naming the option; an input that is not a regular file is a data
error (:class:`~mmsnap_graph.errors.FileFormatError`, exit 1) naming the file.
"""

from __future__ import annotations

import argparse
import glob
import os
import stat
from typing import Iterator

from mmsnap_graph._atomic import check_output_path, file_kind
from mmsnap_graph.app.commands.arguments import check_sigmas
from mmsnap_graph.errors import FileFormatError, ValidationError

__all__ = ["OUTPUT_FILE_OPTIONS", "OUTPUT_FOLDER_OPTIONS", "add_overwrite", "input_paths", "check_files", "same_file",
           "written_files"]

#: Per command, the options naming an output file.
OUTPUT_FILE_OPTIONS: dict[str, tuple[str, ...]] = {
    "process": ("output",), "fuse": ("output",), "calibrate": ("json_out", "output"),
    "simulate": ("output",), "replay": ("output", "view_log"), "import": ("output",),
    "noise": ("output",), "monitor": ("json_out",), "batch": ("json_out",),
    "export": ("output",), "record": ("output",), "live": ("output", "record", "view_log"),
    "plot": ("output",),
}

#: Per command, the options naming a folder the command writes files into.
OUTPUT_FOLDER_OPTIONS: dict[str, tuple[str, ...]] = {"demo": ("out",), "batch": ("output_dir",)}

#: Options that are glob patterns of input files (``mmsnap batch``).
_PATTERN_OPTIONS = ("patterns",)
#: Options never naming an input file.
_NOT_INPUTS = ("command", "func", "output_dir", "out")


def add_overwrite(parser: argparse.ArgumentParser, help: str | None = None) -> None:
    """The ``--overwrite`` flag every verb writing a named file has."""
    parser.add_argument("--overwrite", action="store_true",
                        help=help or "replace an existing output file (default: refuse)")


def _strings(value) -> Iterator[str]:
    if isinstance(value, (str, os.PathLike)):
        yield os.fspath(value)
    elif isinstance(value, (list, tuple)):
        for v in value:
            yield from _strings(v)


def input_paths(args: argparse.Namespace) -> list[str]:
    """Every existing file the command line names outside its output
    options (the recording, ``--calibration``, ``--poses``, ``--config``,
    the tables and logs of ``import``, the recordings of ``batch``)."""
    outputs = OUTPUT_FILE_OPTIONS.get(args.command, ())
    found = []
    for name, value in vars(args).items():
        if name in outputs or name in _NOT_INPUTS:
            continue
        for text in _strings(value):
            if name in _PATTERN_OPTIONS:
                found.extend(h for h in glob.glob(text, recursive=True) if os.path.exists(h))
            elif text and os.path.lexists(text):
                found.append(text)
    return found


def same_file(a: str | os.PathLike, b: str | os.PathLike) -> bool:
    """Whether the paths name the same file (through symlinks or hard links)."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        return os.path.realpath(a) == os.path.realpath(b)


def _check_input(path: str) -> None:
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return  # a dangling link or unreadable entry: the reader says why
    if not (stat.S_ISREG(mode) or stat.S_ISDIR(mode)):
        raise FileFormatError(f"{path} is not a regular file (a FIFO, device or socket); "
                              "give a recording file")


def _is_written(args: argparse.Namespace, name: str) -> bool:
    """Whether the output option ``name`` will be written in this run."""
    return not (name == "output" and getattr(args, "no_write", False))


def written_files(args: argparse.Namespace) -> Iterator[tuple[str, str]]:
    """``(option, path)`` of every file the parsed command line writes
    besides its recording: the output options of :data:`OUTPUT_FILE_OPTIONS`
    that this run writes, and ``mmsnap calibrate``'s calibration JSON beside
    the recording when no ``--json-out`` names it."""
    for name in OUTPUT_FILE_OPTIONS.get(args.command, ()):
        value = getattr(args, name, None)
        if value is None or not isinstance(value, (str, os.PathLike)) \
                or not _is_written(args, name):
            continue
        yield "--" + name.replace("_", "-"), os.fspath(value)
    recording = getattr(args, "recording", None)
    if args.command == "calibrate" and not args.json_out \
            and isinstance(recording, (str, os.PathLike)) and not args.show_config:
        from mmsnap_graph.app.runs import calibration_json_path

        yield "the calibration JSON (--json-out)", os.fspath(calibration_json_path(recording))


def _check_folder(option: str, path: str) -> None:
    """An output folder is a folder or nothing yet (it is made)."""
    try:
        mode = os.stat(path).st_mode
    except (FileNotFoundError, NotADirectoryError):
        return
    if not stat.S_ISDIR(mode):
        raise ValidationError(f"{option} {path}: it is {file_kind(mode)}, not a folder; give a "
                              "folder (the files are written inside it)")


def check_files(args: argparse.Namespace) -> None:
    """Apply the module's rule to the parsed command line ``args`` (its
    ``command`` names the verb). Raises :class:`ValidationError` naming the
    output option (or ``--sigmas``, checked here for every verb), or
    :class:`FileFormatError` naming an input file."""
    if getattr(args, "sigmas", None) is not None:
        check_sigmas(args.sigmas)
    inputs = input_paths(args)
    for path in inputs:
        _check_input(path)
    for name in OUTPUT_FOLDER_OPTIONS.get(args.command, ()):
        value = getattr(args, name, None)
        if isinstance(value, (str, os.PathLike)):
            _check_folder("--" + name.replace("_", "-"), os.fspath(value))
    for option, value in written_files(args):
        try:
            check_output_path(value)
        except FileFormatError as exc:
            raise ValidationError(f"{option}: {exc}") from None
        if not os.path.lexists(value):
            continue
        for path in inputs:
            if same_file(value, path):
                hint = (" (omit it to update the recording in place)"
                        if option == "--output" and args.command in ("process", "calibrate",
                                                                     "fuse", "noise") else "")
                raise ValidationError(f"{option} {value} is the input file {path}: writing it "
                                      f"would destroy the input; give another path{hint}")
        if not getattr(args, "overwrite", False):
            raise ValidationError(f"{option}: {value} exists; pass --overwrite to replace it")
