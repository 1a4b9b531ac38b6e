"""One pipeline, three drivers: the real recordings of ``data/real/darksz`` and
three simulated ones through ``mmsnap fuse`` (windowed), ``mmsnap batch``
(the same, in a worker) and ``mmsnap replay`` (the stream), as a user runs
them (docs/STREAMING.md, "One pipeline").

- ``fuse`` and ``batch``: the same rows, every field.
- ``replay --delay 9`` (the checks' look-around, ``DEFAULT_CONFIG.context_frames``,
  given to the stream): the rows a stream can decide from the frames it holds
  get ``fuse``'s status and state (to 1e-9); the rows it cannot are those
  near a learned wall (learned from the whole recording by ``fuse``, from the
  frames so far by the stream): each differing row is beyond a learned wall
  on one side, and the test prints how many.
- ``replay --delay 0`` (every decision from past frames only, what ``mmsnap
  live`` does): the same association; the test prints how many rows differ
  (the motion, coverage and split checks without the frames after the row).

The replays use the vectorized solver, ``fuse``'s. ``pytest -s`` shows the counts.
Each recording's replays are tests of their own (parametrized), so that the
test command's two workers share them; each recording and its ``fuse`` output
are made once per run (``_once.built_once``), ``batch`` runs on all of them.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from _once import built_once
from _shared import DATA
from mmsnap_graph.app.cli import main
from mmsnap_graph.data.results import Status
from mmsnap_graph.fusion.config import DEFAULT_CONFIG
from mmsnap_graph.io.fused import read_fused

REAL = DATA / "real" / "darksz"
#: S2's mounting height of each real recording (data/real/darksz/README.md).
REAL_S2_HEIGHT_M = {"multiple_tracking": 1.1, "fall_detection": 2.45}
#: The simulated recordings: multipath ghosts in a small room of three radars
#: at 20 fps, two people in network C, and one person in network A calibrated
#: from the data (pose covariances and clock offsets in the fusion).
SIMULATED = {
    "ghosts": ["--node", "S1=0,0,0", "--node", "S2=4,0,60", "--node", "S3=2,6,180", "-t",
               "random", "-n", "300", "--frame-period", "0.05", "-s", "3", "--known-poses"],
    "two_people": ["-c", "C", "-t", "random", "--targets", "2", "-n", "300", "-s", "5",
                   "--known-poses"],
    "calibrated": ["-c", "A", "-t", "random", "-n", "300", "-s", "7"],
}
ROW_FIELDS = ("frame", "target", "detection_index", "observed", "status", "track_id")
CLOSE_FIELDS = ("state", "covariance")


def run(*argv: str) -> None:
    assert main(list(argv)) == 0, f"mmsnap {' '.join(argv)} failed"


NAMES = [*REAL_S2_HEIGHT_M, *SIMULATED]


def _make(folder: Path, stem: str) -> Path:
    """``folder/STEM.h5`` as a user makes it: a real recording imported,
    processed and calibrated; a simulated one simulated (processed and
    calibrated when its poses are not known)."""
    out = folder / f"{stem}.h5"
    if stem in REAL_S2_HEIGHT_M:
        run("import", "table", "--node", f"S1={REAL / f'{stem}_S1.csv'}",
            "--node", f"S2={REAL / f'{stem}_S2.csv'}", "--frame-period", "0.05",
            "--mount", "S1=0.8,0", "--mount", f"S2={REAL_S2_HEIGHT_M[stem]},0",
            "--room-pose", "S1=0,0,0", "--room-pose", "S2=1.7,1.65,90",
            "--height-band", "0.2,2.0", "-o", str(out))
    else:
        run("simulate", *SIMULATED[stem], "-o", str(out), "--no-progress")
    if stem in REAL_S2_HEIGHT_M or "--known-poses" not in SIMULATED[stem]:
        run("process", str(out))
        run("calibrate", str(out))
    return out


@pytest.fixture(scope="module")
def prepared(tmp_path_factory):
    """``prepared(stem)``: a folder holding ``recs/STEM.h5`` (:func:`_make`)
    and ``fuse.h5``, its ``mmsnap fuse``; made once per run, each recording
    apart so that a test waits only for the one it reads."""
    def build(stem: str, folder: Path) -> None:
        (folder / "recs").mkdir()
        run("fuse", str(_make(folder / "recs", stem)), "-o", str(folder / "fuse.h5"),
            "--no-progress", "--max-flagged", "1")

    return lambda stem: built_once(tmp_path_factory, f"fusion_paths-{stem}",
                                   lambda folder: build(stem, folder))


def _replay(folder: Path, stem: str, delay: int, out: Path) -> dict:
    run("replay", str(folder / "recs" / f"{stem}.h5"), "--solver", "vectorized", "--delay",
        str(delay), "--summary", "-o", str(out))
    return _stream_rows(out)


def _stream_rows(path: Path) -> dict:
    """(frame, detection index per node) -> (status, state) of a replay's JSON lines."""
    rows = {}
    for line in path.read_text().splitlines():
        r = json.loads(line)
        for g, index in enumerate(r["detection_index"]):
            rows[(r["frame"], tuple(index))] = (r["status"][g], np.array(r["state"][g], float))
    return rows


def _compare(fused, stream: dict) -> tuple[int, list]:
    """(rows identical, differing rows as (fuse status, stream status))."""
    keys = [(int(f), tuple(int(v) for v in d)) for f, d in zip(fused.frame, fused.detection_index)]
    assert set(keys) == set(stream), "the stream's rows are not fuse's (association)"
    same, differ = 0, []
    for i, key in enumerate(keys):
        status, state = stream[key]
        if status == fused.status[i] and np.allclose(state, fused.state[i], rtol=0, atol=1e-9,
                                                     equal_nan=True):
            same += 1
        else:
            differ.append((int(fused.status[i]), int(status)))
    return same, differ


@pytest.mark.slow
def test_fuse_and_batch_write_the_same_rows(prepared, tmp_path):
    folders = {stem: prepared(stem) for stem in NAMES}
    run("batch", *[str(f / "recs" / "*.h5") for f in folders.values()], "--steps", "fuse",
        "--workers", "1", "--output-dir", str(tmp_path), "--no-progress")
    assert sorted(p.stem for p in tmp_path.glob("*.h5")) == sorted(NAMES)
    for stem, folder in folders.items():
        a, b = read_fused(folder / "fuse.h5"), read_fused(tmp_path / f"{stem}.h5")
        assert len(a) == len(b) > 0, stem
        for k in ROW_FIELDS:
            np.testing.assert_array_equal(getattr(a, k), getattr(b, k), err_msg=f"{stem} {k}")
        for k in CLOSE_FIELDS:
            np.testing.assert_allclose(getattr(a, k), getattr(b, k), rtol=0, atol=1e-9,
                                       err_msg=f"{stem} {k}")


@pytest.mark.slow
@pytest.mark.parametrize("stem", NAMES)
def test_the_stream_with_the_look_around_gives_fuses_rows_but_near_learned_walls(prepared, stem,
                                                                                 tmp_path):
    assert DEFAULT_CONFIG.context_frames == 9
    folder = prepared(stem)
    fused = read_fused(folder / "fuse.h5")
    same, differ = _compare(fused, _replay(folder, stem, 9, tmp_path / "replay9.jsonl"))
    kinds = {k: differ.count(k) for k in sorted(set(differ))}
    print(f"{stem}: replay --delay 9 against fuse: {same} of {len(fused)} rows identical, "
          f"{len(differ)} differ (fuse status, stream status): {kinds}")
    wall = Status.OUTSIDE_BOUNDS
    # the learned walls (from the rows so far in the stream, from the whole recording
    # in fuse) and, rarely, the motion check's refits near a placement decision
    # (measured: 3 of the ghost recording's rows fuse flags MOTION_INCONSISTENT)
    motion = [pair for pair in differ if wall not in pair]
    assert all(pair == (Status.MOTION_INCONSISTENT, Status.OK) for pair in motion), (stem, kinds)
    assert len(motion) <= 0.01 * len(fused), (stem, kinds)
    assert len(differ) <= 0.1 * len(fused), (stem, len(differ))


@pytest.mark.slow
@pytest.mark.parametrize("stem", NAMES)
def test_the_causal_stream_associates_the_same_and_says_how_much_differs(prepared, stem,
                                                                         tmp_path):
    folder = prepared(stem)
    fused = read_fused(folder / "fuse.h5")
    same, differ = _compare(fused, _replay(folder, stem, 0, tmp_path / "replay0.jsonl"))
    kinds = {k: differ.count(k) for k in sorted(set(differ))}
    print(f"{stem}: replay --delay 0 against fuse: {same} of {len(fused)} rows identical, "
          f"{len(differ)} differ (fuse status, stream status): {kinds}")
    # Measured 86-100% identical (docs/STREAMING.md): a regression bound.
    assert same >= 0.75 * len(fused), (stem, same, len(fused))
