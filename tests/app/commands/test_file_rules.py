"""The one rule of every verb's files (mmsnap_graph.app.commands.file_rules): an
output that is an input is refused, an existing output is replaced only with
--overwrite, an input that is a FIFO is refused. Each refusal leaves every
file as it was."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from mmsnap_graph.app.cli import main


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
    "calibrate -o": (["calibrate", "{rec}", "-o", "{out}"], "out"),
    "calibrate --json-out": (["calibrate", "{rec}", "--json-out", "{out}"], "out"),
    "calibrate REC.calibration.json": (["calibrate", "{out_rec}"], "out.calibration.json"),
    "calibrate --no-write REC.calibration.json": (["calibrate", "{out_rec}", "--no-write"],
                                                  "out.calibration.json"),
    "monitor --json-out": (["monitor", "{rec}", "--json-out", "{out}"], "out"),
    "batch --json-out": (["batch", "{rec}", "--json-out", "{out}", "--no-progress"], "out"),
    "demo --out": (["demo", "--simulate", "-c", "B", "-t", "straight", "-n", "20",
                    "--no-figures", "--out", "{out}"], "out"),
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


def _special_targets(folder: Path, name: str) -> dict[str, Path]:
    """``folder/<kind>/<name>`` for each kind: a character device (the
    numbers of /dev/null, made here: never the machine's own /dev), a FIFO,
    a symlink to each, a directory."""
    import stat

    made = {}
    for kind in ("device", "fifo", "link to device", "link to fifo", "directory"):
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
    return made


def _state(folder: Path) -> dict:
    """Every entry under ``folder``: its inode, type, device numbers and link."""
    out = {}
    for p in sorted(folder.rglob("*")):
        st = os.lstat(p)
        out[str(p)] = (st.st_ino, st.st_mode, st.st_rdev,
                       os.readlink(p) if p.is_symlink() else None)
    return out


@pytest.fixture(scope="module")
def fused(good, tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("fused") / "rec.h5"
    path.write_bytes(good.read_bytes())
    assert main(["fuse", str(path), "--no-progress"]) == 0
    return path


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="POSIX FIFOs and device nodes")
def test_no_writer_replaces_a_device_a_fifo_a_link_to_them_or_a_folder(
        good, fused, tmp_path, capsys):
    """Every verb's every written file aimed at a device node, a FIFO, a
    symlink to each and a directory, all made in a scratch folder, with and
    without --overwrite: each is refused (exit 2, naming the path and what it
    is) and none is replaced, nothing left beside it. Before: each was
    renamed over (the error without --overwrite even advised it)."""
    csv = tmp_path / "points.csv"
    csv.write_text("frame,x,y,doppler\n" + "".join(f"{k},0.5,{2 + 0.05 * k},0.1\n"
                                                    for k in range(20)))
    from _rosbags import write_bag
    bag = write_bag(tmp_path / "bag", {"/radar": [
        (10**9 + k * 10**8, 10**9 + k * 10**8, [[0.5, 2 + 0.05 * k, 0.0]], [0.1], [20.0])
        for k in range(20)]}, ros=2)
    refused = 0
    for verb, (template, name) in EVERY_WRITER.items():
        folder = tmp_path / verb.replace(" ", "_").replace("-", "")
        targets = _special_targets(folder, name)
        if verb.startswith("demo"):
            targets.pop("directory")  # its output is a folder
        for kind, target in targets.items():
            out_rec = target.with_name("out.h5")
            if "{out_rec}" in template:
                out_rec.write_bytes(good.read_bytes())
            before = _state(folder)
            for extra in ([], ["--overwrite"]):
                if verb.startswith("demo") and extra:
                    continue
                argv = _argv(template, rec=good, fused=fused, csv=csv, bag=bag, out=target,
                             out_rec=out_rec) + extra
                code = main(argv)
                err = capsys.readouterr().err
                what = ("directory" if kind == "directory" else
                        "a character device" if kind.endswith("device") else "a FIFO")
                assert code == 2, (verb, kind, extra, err)
                assert str(target) in err and what in err, (verb, kind, extra, err)
                assert _state(folder) == before, (verb, kind, extra)
                refused += 1
    assert refused >= 9 * len(EVERY_WRITER)
