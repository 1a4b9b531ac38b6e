"""``kill -9`` of a writer (issue 13: "no data lost under kill -9"): a
``mmsnap process``, ``calibrate`` or ``fuse`` killed at any moment leaves the
recording readable and either unchanged or fully updated (never half
written), and the next run of the verb succeeds and leaves no temporary
file behind."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

from mmsnap_graph.app.cli import main
from mmsnap_graph.io import read_recording

pytestmark = [pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals"),
              pytest.mark.slow]  # subprocesses: about 20 s on a quiet machine

VERBS = {
    "process": ["--centroids-only", "--no-progress"],
    "calibrate": [],
    "fuse": ["--no-progress"],
}
#: When the writer is killed: as soon as its temporary file appears (in the
#: middle of writing), or a fixed time after its start (s).
KILL_WHEN = ("writing", 0.8)


def _kill_when(proc: subprocess.Popen, folder: Path, when) -> None:
    if when == "writing":
        deadline = time.monotonic() + 120
        while proc.poll() is None and time.monotonic() < deadline:
            if any(p.name.endswith(".tmp") for p in folder.iterdir()):
                break
            time.sleep(0.002)
    else:
        time.sleep(when)
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=60)


def digest(path: Path) -> dict:
    """Every dataset and attribute of the file, as bytes (the file's content)."""
    out = {}

    def as_bytes(value) -> bytes:
        arr = np.asarray(value)
        return repr(arr.tolist()).encode() if arr.dtype.kind in "OSU" else arr.tobytes()

    def visit(name, obj):
        for key, value in obj.attrs.items():
            out[f"{name}@{key}"] = as_bytes(value)
        if isinstance(obj, h5py.Dataset):
            out[name] = as_bytes(obj[()])

    with h5py.File(path, "r") as f:
        visit("/", f)
        f.visititems(visit)
    return out


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    """The original recording and, per verb, the file after a full run."""
    d = tmp_path_factory.mktemp("kill9")
    good = d / "good.h5"
    assert main(["simulate", "--model", "clean", "-c", "B", "-t", "random", "-n", "120", "-l", "centroids",
                 "--seed", "2", "--known-poses", "-o", str(good), "--no-progress"]) == 0
    done = {}
    for verb, options in VERBS.items():
        ref = d / f"ref_{verb}.h5"
        shutil.copy(good, ref)
        assert main([verb, str(ref), *options]) == 0
        done[verb] = digest(ref)
    return good, digest(good), done


@pytest.mark.parametrize("verb", sorted(VERBS))
def test_a_killed_writer_leaves_the_recording_unchanged_or_updated(recordings, tmp_path, verb):
    good, before, after = recordings
    outcomes = []
    for i, when in enumerate(KILL_WHEN):
        folder = tmp_path / f"trial{i}"
        folder.mkdir()
        path = folder / "rec.h5"
        shutil.copy(good, path)
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
        proc = subprocess.Popen([sys.executable, "-m", "mmsnap_graph", verb, str(path),
                                 *VERBS[verb]], stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL, env=env)
        _kill_when(proc, folder, when)
        read_recording(path)  # readable
        now = digest(path)
        assert now in (before, after[verb]), f"{verb} killed ({when}): half written"
        outcomes.append("unchanged" if now == before else "updated")
        # The next run succeeds (the lock died with the writer) and removes
        # the killed writer's temporary file (calibrate: the JSON the killed
        # run may have written first is replaced only with --overwrite).
        again = ["--overwrite"] if verb == "calibrate" else []
        assert main([verb, str(path), *VERBS[verb], *again]) == 0
        assert digest(path) == after[verb]
        assert not [p.name for p in folder.iterdir() if p.name.endswith(".tmp")]
    # Killed while its temporary file existed: the recording is the original.
    assert outcomes[0] == "unchanged"
