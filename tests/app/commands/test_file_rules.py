"""The one rule of every verb's files (mmsnap_graph.app.commands.file_rules): an
output that is an input is refused, an existing output is replaced only with
--overwrite, an input that is a FIFO is refused. Each refusal leaves every
file as it was."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from mmsnap_graph.app.cli import build_parser, main
from mmsnap_graph.app.commands.file_rules import OUTPUT_FILE_OPTIONS

from _shared import TI_DATA


@pytest.fixture(scope="module")
def good(recording_b_real_file) -> Path:
    """A small recording with known poses (and truth): the shared one, read only."""
    return recording_b_real_file


@pytest.fixture()
def rec(good, tmp_path) -> Path:
    """A fresh copy of the recording in the test's own folder."""
    path = tmp_path / "rec.h5"
    path.write_bytes(good.read_bytes())
    return path


#: Each verb's option naming a side output (JSON), with what the verb needs besides.
SIDE_OUTPUTS = {
    "replay": ["replay", "{rec}", "--summary", "-o", "{out}"],
    "monitor": ["monitor", "{rec}", "--json-out", "{out}"],
    "batch": ["batch", "{rec}", "--json-out", "{out}", "--no-progress"],
    "calibrate": ["calibrate", "{rec}", "--json-out", "{out}"],
}
#: Each verb's -o (a copy of the recording, or JSON lines for replay).
COPY_OUTPUTS = {
    "process": ["process", "{rec}", "-o", "{out}", "--no-progress"],
    "calibrate": ["calibrate", "{rec}", "-o", "{out}"],
    "fuse": ["fuse", "{rec}", "-o", "{out}", "--no-progress"],
    "noise": ["noise", "{rec}", "-o", "{out}"],
    "replay": ["replay", "{rec}", "--summary", "-o", "{out}"],
    "monitor": ["monitor", "{rec}", "--json-out", "{out}"],
    "batch": ["batch", "{rec}", "--json-out", "{out}", "--no-progress"],
}


def _argv(template, **paths):
    return [a.format(**{k: str(v) for k, v in paths.items()}) for a in template]


def _how(rec: Path, tmp_path: Path, how: str) -> Path:
    """The recording under another name: itself, a relative path, a symlink, a hard link."""
    if how == "same":
        return rec
    if how == "relative":
        return Path(os.path.relpath(rec))
    other = tmp_path / f"{how}.h5"
    (os.symlink if how == "symlink" else os.link)(rec, other)
    return other


@pytest.mark.parametrize("how", ["same", "relative", "symlink", "hardlink"])
@pytest.mark.parametrize("verb", sorted(SIDE_OUTPUTS))
def test_a_side_output_that_is_the_input_is_refused(rec, tmp_path, capsys, verb, how):
    before = rec.read_bytes()
    out = _how(rec, tmp_path, how)
    code = main(_argv(SIDE_OUTPUTS[verb], rec=rec, out=out) + ["--overwrite"])
    err = capsys.readouterr().err
    assert code == 2, err
    assert "is the input file" in err and "would destroy the input" in err
    assert rec.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


@pytest.mark.parametrize("verb", ["process", "calibrate", "fuse", "noise"])
def test_a_copy_onto_the_input_says_to_update_in_place(rec, tmp_path, capsys, verb):
    before = rec.read_bytes()
    code = main(_argv(COPY_OUTPUTS[verb], rec=rec, out=_how(rec, tmp_path, "symlink"))
                + ["--overwrite"])
    err = capsys.readouterr().err
    assert code == 2 and "omit it to update the recording in place" in err
    assert rec.read_bytes() == before


@pytest.mark.parametrize("verb", sorted(COPY_OUTPUTS))
def test_an_existing_output_needs_overwrite(rec, tmp_path, capsys, verb):
    out = tmp_path / "precious.txt"
    out.write_text("keep me\n")
    before = rec.read_bytes()
    code = main(_argv(COPY_OUTPUTS[verb], rec=rec, out=out))
    err = capsys.readouterr().err
    assert code == 2, err
    assert "exists; pass --overwrite to replace it" in err and "--" in err
    assert out.read_text() == "keep me\n"
    assert rec.read_bytes() == before


@pytest.mark.parametrize("verb", ["replay", "monitor", "fuse"])
def test_overwrite_replaces_an_existing_output(rec, tmp_path, capsys, verb):
    out = tmp_path / "old.out"
    out.write_text("old\n")
    code = main(_argv(COPY_OUTPUTS[verb], rec=rec, out=out) + ["--overwrite"])
    capsys.readouterr()
    assert code == 0
    assert out.read_bytes() != b"old\n"


#: Commands reading a FIFO (as the recording, a calibration JSON, --poses).
FIFO_ARGVS = [
    ["evaluate", "{fifo}"], ["monitor", "{fifo}"], ["replay", "{fifo}", "--summary"],
    ["noise", "{fifo}", "--no-write"], ["fuse", "{fifo}", "--no-progress"],
    ["calibrate", "{fifo}"], ["process", "{fifo}", "--no-progress"],
    ["fuse", "{rec}", "--calibration", "{fifo}", "--no-progress"],
    ["monitor", "{rec}", "--poses", "{fifo}"],
]


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="POSIX FIFOs")
def test_a_fifo_input_is_refused_at_once(rec, tmp_path):
    # In a child process: h5py blocks on a FIFO holding the GIL, so a hang
    # must be ended from outside.
    fifo = tmp_path / "fifo.h5"
    os.mkfifo(fifo)
    argvs = [_argv(a, rec=rec, fifo=fifo) for a in FIFO_ARGVS]
    script = ("import json, sys, time\nfrom mmsnap_graph.app.cli import main\n"
              "for argv in json.loads(sys.argv[1]):\n"
              "    t0 = time.monotonic(); code = main(argv)\n"
              "    print(json.dumps([argv[0], code, time.monotonic() - t0]), flush=True)\n")
    proc = subprocess.run([sys.executable, "-c", script, json.dumps(argvs)],
                          capture_output=True, text=True, timeout=60)
    results = [json.loads(line) for line in proc.stdout.splitlines()]
    assert len(results) == len(argvs), proc.stderr
    assert [code for _, code, _ in results] == [1] * len(argvs), proc.stderr
    assert max(t for _, _, t in results[1:]) < 1.0  # the first one imports the CLI
    errors = proc.stderr.splitlines()
    assert len(errors) == len(argvs) and "Traceback" not in proc.stderr
    assert all("fifo.h5 is not a regular file" in e for e in errors)


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="POSIX FIFOs")
def test_the_library_reader_refuses_a_fifo(tmp_path):
    from mmsnap_graph.errors import FileFormatError
    from mmsnap_graph.io import read_recording

    fifo = tmp_path / "fifo.h5"
    os.mkfifo(fifo)
    with pytest.raises(FileFormatError, match="not a regular file"):
        read_recording(fifo)


def test_an_update_through_a_symlink_keeps_the_link(rec, tmp_path, capsys):
    link = tmp_path / "link.h5"
    link.symlink_to(rec)
    before = rec.read_bytes()
    assert main(["fuse", str(link), "--no-progress"]) == 0, capsys.readouterr().err
    assert link.is_symlink() and link.resolve() == rec.resolve()
    assert rec.read_bytes() != before  # the target got its /fused group
    assert sorted(p.name for p in tmp_path.iterdir()) == ["link.h5", "rec.h5"]


#: Every verb's written files, as (argv template, name of the written file):
#: ``{out}`` is the file written, ``{rec}`` a recording (``{fused}`` one with
#: /fused), ``{csv}`` a point table, ``{bag}`` a ROS 2 bag of one PointCloud2 topic.
EVERY_WRITER = {
    "export": (["export", "{fused}", "fused", "-o", "{out}"], "out"),
    "simulate": (["simulate", "-c", "B", "-n", "20", "-l", "centroids", "--seed", "3",
                  "-o", "{out}", "--no-progress"], "out"),
    "fuse -o": (["fuse", "{rec}", "-o", "{out}", "--no-progress"], "out"),
    "process -o": (["process", "{rec}", "-o", "{out}", "--no-progress"], "out"),
    "noise -o": (["noise", "{rec}", "-o", "{out}"], "out"),
    "replay -o": (["replay", "{rec}", "--summary", "-o", "{out}"], "out"),
    "replay --view-log": (["replay", "{rec}", "--summary", "--view-log", "{out}"], "out"),
    "plot -o": (["plot", "{fused}", "-o", "{out}"], "out.png"),
    "import table -o": (["import", "table", "--node", "S1={csv}", "--frame-period", "0.1",
                         "-o", "{out}"], "out"),
    "import rosbag -o": (["import", "rosbag", "{bag}", "--topic", "/radar=S1", "--frame-period",
                          "0.1", "-o", "{out}"], "out"),
    "import dca1000 -o": (["import", "dca1000", "--cfg", "{dca_cfg}", "--board", "AWR1843BOOST",
                           "--sub-frame", "0", "--node", "S1={dca_bin}", "-o", "{out}"], "out"),
    "import ti-uart -o": (["import", "ti-uart", "--node", "S1={uart}", "--cfg", "{uart_cfg}",
                           "-o", "{out}"], "out"),
    "calibrate -o": (["calibrate", "{rec}", "-o", "{out}"], "out"),
    "calibrate --json-out": (["calibrate", "{rec}", "--json-out", "{out}"], "out"),
    "calibrate REC.calibration.json": (["calibrate", "{out_rec}"], "out.calibration.json"),
    "calibrate --no-write REC.calibration.json": (["calibrate", "{out_rec}", "--no-write"],
                                                  "out.calibration.json"),
    "monitor --json-out": (["monitor", "{rec}", "--json-out", "{out}"], "out"),
    "batch --json-out": (["batch", "{rec}", "--json-out", "{out}", "--no-progress",
                          "--steps", "fuse"], "out"),
    "demo --out": (["demo", "--simulate", "-c", "B", "-t", "straight", "-n", "20",
                    "--no-figures", "--out", "{out}"], "out"),
    "batch --output-dir": (["batch", "{rec}", "--output-dir", "{out}", "--no-progress"], "out"),
    # the boards' verbs: refused before any port is opened (none named exists)
    "record -o": (["record", "--board", "S1=usb:NO_SUCH_BOARD", "--duration", "1",
                   "-o", "{out}"], "out"),
    "live -o": (["live", "--calibration", "{rec}", "--board", "S1=usb:NO_SUCH_BOARD",
                 "--duration", "1", "-o", "{out}"], "out"),
    "live --record": (["live", "--calibration", "{rec}", "--board", "S1=usb:NO_SUCH_BOARD",
                       "--duration", "1", "--record", "{out}"], "out"),
    "live --view-log": (["live", "--calibration", "{rec}", "--board", "S1=usb:NO_SUCH_BOARD",
                         "--duration", "1", "--view-log", "{out}"], "out"),
}


#: The verbs whose written path is a folder (its files are written inside).
FOLDER_WRITERS = ("demo --out", "batch --output-dir")
#: The TI samples the imports of EVERY_WRITER read.
TI_INPUTS = dict(dca_cfg=TI_DATA / "dca1000_small.cfg", dca_bin=TI_DATA / "dca1000_small.bin",
                 uart=TI_DATA / "oob_uart_S1.bin", uart_cfg=TI_DATA / "iwr1843_oob.cfg")


def _leaf_parsers(parser=None, path=()):
    """``(verb path, parser)`` of every command the CLI has (``import
    table`` is ``("import", "table")``), from argparse itself."""
    import argparse

    parser = build_parser() if parser is None else parser
    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not subs:
        yield path, parser
        return
    for name, sub in subs[0].choices.items():
        yield from _leaf_parsers(sub, path + (name,))


#: An option naming a written path: its dest or its help says so.
_WRITTEN_DEST = re.compile(r"(?:^|_)(?:out|output|record|log|dir)(?:_|$)")
_WRITTEN_HELP = re.compile(r"^(?:also )?(?:write|output)\b", re.IGNORECASE)
#: Options the rule above matches that name no written path (none today).
NOT_WRITTEN: dict[tuple, str] = {}


def cli_written_options() -> set[tuple]:
    """``(verb path, option)`` of every option of every command that names a
    path the command writes, found in the parsers (so that a new verb or
    option is found without being listed anywhere)."""
    found = set()
    for path, parser in _leaf_parsers():
        for action in parser._actions:
            if not action.option_strings or action.nargs == 0:
                continue
            if _WRITTEN_DEST.search(action.dest) or _WRITTEN_HELP.search(action.help or ""):
                key = (path, action.option_strings[-1])
                if key not in NOT_WRITTEN:
                    found.add(key)
    return found


def _written_option(template) -> tuple:
    """``(verb path, option)`` an EVERY_WRITER template aims at ``{out}``
    (None for the calibration JSON beside the recording)."""
    commands = {path for path, _ in _leaf_parsers()}
    path = next(tuple(template[:n]) for n in (2, 1) if tuple(template[:n]) in commands)
    if "{out}" not in template:
        return path, None
    return path, template[template.index("{out}") - 1]


def _options(template) -> set[str]:
    """The option strings of the command of ``template``."""
    path = _written_option(template)[0]
    parser = dict(_leaf_parsers())[path]
    return {s for a in parser._actions for s in a.option_strings}


def test_every_written_option_of_the_cli_is_in_the_every_writer_test():
    """The options naming a written path, found in the CLI's parsers
    (argparse), are each aimed at a device, a FIFO, links and a folder by
    the test below, and each (but a folder's) is checked by the file rule
    (file_rules.OUTPUT_FILE_OPTIONS): a new verb or output option that
    either misses fails here."""
    found = cli_written_options()
    long = {(p, o) for p, o in found}
    covered = {_written_option(t) for t, _ in EVERY_WRITER.values()}
    covered.discard(None)
    names = {(p, o) for p, o in covered if o is not None}
    # -o and its long form name one option
    aliases = {}
    for path, parser in _leaf_parsers():
        for a in parser._actions:
            for s_ in a.option_strings:
                aliases[(path, s_)] = (path, a.option_strings[-1])
    assert {aliases[k] for k in names} == long, (long - {aliases[k] for k in names},
                                                 {aliases[k] for k in names} - long)
    assert len(long) >= 22, sorted(long)  # 22 on 2026-12-02
    folders = {aliases[_written_option(EVERY_WRITER[v][0])] for v in FOLDER_WRITERS}
    for path, option in long - folders:
        dest = option.lstrip("-").replace("-", "_")
        assert dest in OUTPUT_FILE_OPTIONS.get(path[0], ()), (path, option)


def _special_targets(folder: Path, name: str) -> dict[str, Path]:
    """``folder/<kind>/<name>`` for each kind: a character device (the
    numbers of /dev/null, made here: never the machine's own /dev), a FIFO,
    a symlink to each, a directory."""
    import stat

    made = {}
    for kind in ("device", "fifo", "link to device", "link to fifo", "directory",
                 "existing file", "link to a file elsewhere"):
        d = folder / kind.replace(" ", "_")
        d.mkdir(parents=True)
        made[kind] = d / name
    try:
        os.mknod(made["device"], stat.S_IFCHR | 0o600, os.makedev(1, 3))
    except PermissionError:  # not root: no device node here
        for kind in ("device", "link to device"):
            made.pop(kind)
    os.mkfifo(made["fifo"])
    for kind in ("device", "fifo"):
        if kind in made:
            made[f"link to {kind}"].symlink_to(made[kind])
    made["directory"].mkdir()
    made["existing file"].write_text("keep me\n")
    elsewhere = folder / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / "precious").write_text("keep me too\n")
    made["link to a file elsewhere"].symlink_to(elsewhere / "precious")
    return made


def _state(folder: Path) -> dict:
    """Every entry under ``folder``: its inode, type, device numbers, link
    and (a regular file's) bytes."""
    import stat

    out = {}
    for p in sorted(folder.rglob("*")):
        st = os.lstat(p)
        out[str(p)] = (st.st_ino, st.st_mode, st.st_rdev,
                       os.readlink(p) if p.is_symlink() else None,
                       p.read_bytes() if stat.S_ISREG(st.st_mode) else None)
    return out


@pytest.fixture(scope="module")
def fused(good, tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("fused") / "rec.h5"
    path.write_bytes(good.read_bytes())
    assert main(["fuse", str(path), "--no-progress"]) == 0
    return path


def _writer_inputs(folder: Path, good: Path, fused: Path) -> dict:
    """The inputs EVERY_WRITER's templates name: the recording, one with
    /fused, a point table, a ROS 2 bag of one PointCloud2 topic, the TI samples."""
    from _rosbags import write_bag

    csv = folder / "points.csv"
    csv.write_text("frame,x,y,z,doppler\n" + "".join(f"{k},0.5,{2 + 0.05 * k},0.0,0.1\n"
                                                      for k in range(20)))
    bag = write_bag(folder / "bag", {"/radar": [
        (10**9 + k * 10**8, 10**9 + k * 10**8, [[0.5, 2 + 0.05 * k, 0.0]], [0.1], [20.0])
        for k in range(20)]}, ros=2)
    return dict(rec=good, fused=fused, csv=csv, bag=bag, **TI_INPUTS)


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="POSIX FIFOs and device nodes")
def test_no_writer_replaces_a_device_a_fifo_a_link_a_folder_or_a_file(
        good, fused, tmp_path, capsys):
    """Every verb's every written path (EVERY_WRITER, which the test above
    checks against the CLI's parsers) aimed at a device node, a FIFO, a
    symlink to each and a directory, with and without --overwrite, and at an
    existing file and a symlink to a file in another folder without it, all
    made in a scratch folder: each is refused (exit 2, naming the path and
    what it is) and none is replaced or changed, nothing left beside it (a
    folder writer's: anything but a folder is refused). Before: each device
    or FIFO was renamed over (the error without --overwrite even advised
    it); batch --output-dir on a device failed with 'File exists'."""
    inputs = _writer_inputs(tmp_path, good, fused)
    refused, seen = 0, set()
    for verb, (template, name) in EVERY_WRITER.items():
        folder = tmp_path / verb.replace(" ", "_").replace("-", "")
        targets = _special_targets(folder, name)
        if verb in FOLDER_WRITERS:
            targets.pop("directory")  # its output is a folder
        for kind, target in targets.items():
            out_rec = target.with_name("out.h5")
            if "{out_rec}" in template:
                out_rec.write_bytes(good.read_bytes())
            before = _state(folder)
            for extra in ([], ["--overwrite"]):
                if "--overwrite" not in _options(template) and extra:
                    continue
                argv = _argv(template, out=target, out_rec=out_rec, **inputs) + extra
                if "file" in kind and extra and verb not in FOLDER_WRITERS:
                    continue  # replaced with --overwrite: the next test
                code = main(argv)
                err = capsys.readouterr().err
                what = ("directory" if kind == "directory" else
                        "a character device" if kind.endswith("device") else
                        "a FIFO" if kind.endswith("fifo") else
                        "a regular file, not a folder" if verb in FOLDER_WRITERS else
                        "exists; pass --overwrite")
                assert code == 2, (verb, kind, extra, err)
                assert str(target) in err and what in err, (verb, kind, extra, err)
                assert _state(folder) == before, (verb, kind, extra)
                refused += 1
                seen.add((verb, kind))
    kinds = {k for _, k in seen}
    assert len(kinds) == 7 or (os.geteuid() != 0 and len(kinds) == 5), kinds
    assert {v for v, _ in seen} == set(EVERY_WRITER)
    assert refused >= 11 * len(EVERY_WRITER), refused


#: Writers that cannot finish here (no board on a port; batch's local
#: cluster costs 20 s): checked above without --overwrite only. Their files
#: are written by the same _atomic.atomic_path.
_NOT_RUN_HERE = ("record -o", "live -o", "live --record", "live --view-log", "batch --json-out")


@pytest.mark.skipif(not hasattr(os, "symlink"), reason="POSIX symlinks")
def test_overwrite_through_a_link_replaces_the_file_it_names_and_keeps_the_link(
        good, fused, recording_b_file, tmp_path, capsys):
    """Every writer that can run here, its output a symlink to a regular file
    in another folder, with --overwrite: the file the link names is replaced
    (new bytes, a regular file), the link stays a link to it, and neither
    folder keeps a temporary file; no numpy RuntimeWarning on the way (noise
    -o printed 'invalid value encountered in sqrt' from
    calibration/noise/motion.py)."""
    import time
    import warnings

    inputs = _writer_inputs(tmp_path, good, fused)
    times = {}
    for verb, (template, name) in EVERY_WRITER.items():
        if verb in FOLDER_WRITERS or verb in _NOT_RUN_HERE:
            continue
        folder = tmp_path / verb.replace(" ", "_").replace("-", "")
        (folder / "links").mkdir(parents=True)
        (folder / "elsewhere").mkdir()
        precious = folder / "elsewhere" / name
        precious.write_bytes(b"old bytes\n")
        link = folder / "links" / name
        link.symlink_to(precious)
        out_rec = link.with_name("out.h5")
        # a fresh copy (calibrate updates it); calibrate's of the clean model
        # (one labelled centroid a frame: no tracks needed)
        out_rec.write_bytes((recording_b_file if verb.startswith("calibrate") else good)
                            .read_bytes())
        start = time.monotonic()
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            code = main(_argv(template, out=link, out_rec=out_rec, **{**inputs, "rec": out_rec})
                        + ["--overwrite"])
        # numpy's or a library's own warning reaches the user as a source line
        raw = [f"{w.category.__name__}: {w.message}" for w in caught
               if issubclass(w.category, (RuntimeWarning, DeprecationWarning))]
        assert raw == [], (verb, raw)
        times[verb] = (code, round(time.monotonic() - start, 1))
        err = capsys.readouterr().err
        assert code in (0, 1) and "Traceback" not in err, (verb, code, err)  # noise: 1, none identified
        assert link.is_symlink() and os.readlink(link) == str(precious), verb
        assert precious.is_file() and not precious.is_symlink(), verb
        assert precious.read_bytes() != b"old bytes\n", (verb, err)
        leftovers = [p.name for d in ("links", "elsewhere") for p in (folder / d).iterdir()
                     if p.name.startswith(".")]
        assert leftovers == [], (verb, leftovers)
    assert len(times) == len(EVERY_WRITER) - len(FOLDER_WRITERS) - len(_NOT_RUN_HERE), times
