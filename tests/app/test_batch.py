"""Many recordings in worker processes: ``run_many`` (mmsnap_graph.app.batch)
on a Dask LocalCluster and a ProcessPoolExecutor, and ``mmsnap batch``."""

import json
import shutil
import subprocess
import sys
from concurrent.futures import Executor, Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path

import h5py
import numpy as np
import pytest

from mmsnap_graph.calibration import MatchingOptions
from mmsnap_graph.app.batch import (
    STEPS,
    calibration_json_path,
    local_client,
    run_many,
    run_recording,
)
from mmsnap_graph.app.cli import main
from mmsnap_graph.errors import ValidationError

N_FRAMES = 150
GOOD = ("rec_a.h5", "rec_b.h5")
BAD = "rec_corrupt.h5"


def _simulate(path: Path, seed: int) -> None:
    assert main(["simulate", "--model", "clean", "-c", "B", "-t", "random", "-n", str(N_FRAMES),
                 "-l", "centroids",
                 "--seed", str(seed), "-o", str(path), "--no-progress"]) == 0


@pytest.fixture(scope="module")
def sources(tmp_path_factory):
    """Two good recordings and one whose body is overwritten with garbage
    (its HDF5 superblock intact, so it opens and then fails)."""
    d = tmp_path_factory.mktemp("sources")
    for seed, name in enumerate(GOOD, start=1):
        _simulate(d / name, seed)
    raw = bytearray((d / GOOD[0]).read_bytes())
    rng = np.random.default_rng(0)
    raw[2048:] = rng.integers(0, 256, len(raw) - 2048, dtype=np.uint8).tobytes()
    (d / BAD).write_bytes(bytes(raw))
    return d


@pytest.fixture(scope="module")
def reference(sources, tmp_path_factory):
    """The good recordings run through the commands one by one, in this process."""
    d = tmp_path_factory.mktemp("reference")
    for name in GOOD:
        out = d / name
        assert main(["process", str(sources / name), "-o", str(out), "--no-progress"]) == 0
        assert main(["calibrate", str(out)]) == 0
        assert main(["fuse", str(out), "--no-progress"]) == 0
    return d


def _h5_items(path: Path) -> dict:
    """Every dataset's values and every attribute of a file, by HDF5 path."""
    items = {}
    with h5py.File(path, "r") as f:
        def visit(name, obj):
            for k, v in obj.attrs.items():
                items[f"{name}@{k}"] = v
            if isinstance(obj, h5py.Dataset):
                items[name] = obj[()]
        visit("/", f)
        f.visititems(visit)
    return items


def assert_same_files(got: Path, want: Path) -> None:
    a, b = _h5_items(got), _h5_items(want)
    assert sorted(a) == sorted(b)
    for key in a:
        x, y = np.asarray(a[key]), np.asarray(b[key])
        if x.dtype.kind in "fc":
            np.testing.assert_array_equal(x, y, err_msg=key)
        else:
            assert x.tolist() == y.tolist(), key
    ja = json.loads(calibration_json_path(got).read_text())
    jb = json.loads(calibration_json_path(want).read_text())
    assert ja == jb


def _check_batch(summaries, sources: Path, out_dir: Path, reference: Path) -> None:
    assert [Path(s.path).name for s in summaries] == sorted([*GOOD, BAD])
    by_name = {Path(s.path).name: s for s in summaries}
    bad = by_name[BAD]
    assert not bad.success and bad.steps_done == ()
    assert bad.error.startswith("process: FileFormatError: ")
    assert "\n" not in bad.error
    for name in GOOD:
        s = by_name[name]
        assert s.success, s.error
        assert s.steps_done == STEPS and set(s.durations_s) == set(STEPS)
        assert s.output == str(out_dir / name)
        assert s.counts["n_calibrated"] == 2 and s.counts["n_fused"] >= N_FRAMES - 5
        assert s.peak_rss_mb > 0 and s.worker
        assert_same_files(out_dir / name, reference / name)
    # The inputs are untouched when an output directory is given.
    assert sorted(p.name for p in sources.iterdir()) == sorted([*GOOD, BAD])


@pytest.mark.slow
def test_dask_local_cluster_matches_commands_and_isolates_the_bad_file(
        sources, reference, tmp_path):
    paths = sorted(str(p) for p in sources.iterdir())
    seen = []
    with local_client(2) as client:
        assert len(client.scheduler_info()["workers"]) == 2
        summaries = run_many(paths, client=client, output_dir=tmp_path, on_result=seen.append)
    assert len(seen) == 3
    _check_batch(summaries, sources, tmp_path, reference)


def test_process_pool_matches_commands_and_isolates_the_bad_file(sources, reference, tmp_path):
    paths = sorted(str(p) for p in sources.iterdir())
    with ProcessPoolExecutor(max_workers=2) as pool:
        summaries = run_many(paths, executor=pool, output_dir=tmp_path)
    _check_batch(summaries, sources, tmp_path, reference)


def test_in_place_steps_one_at_a_time_equal_all_at_once(sources, reference, tmp_path):
    """No executor: runs here; steps given separately update the file in place."""
    path = tmp_path / GOOD[1]
    shutil.copyfile(sources / GOOD[1], path)
    for step in STEPS:
        (s,) = run_many([path], [step])
        assert s.success and s.steps_done == (step,) and s.output == str(path)
    assert_same_files(path, reference / GOOD[1])


def test_a_calibration_that_fails_stops_the_recording(sources, tmp_path):
    """calibrate_recording with success=False (pose graph on a one-node
    network is fine, but max_rmse_m tiny rejects every pair): flagged, no fuse."""
    s = run_recording(sources / GOOD[0], output=tmp_path / "x.h5",
                      options={"calibrate": {"matching": MatchingOptions(max_rmse_m=1e-6)}})
    assert not s.success and s.steps_done == ("process",)
    assert s.error.startswith("calibrate: ")
    assert str(tmp_path / "x.h5") in s.outputs


class _DyingExecutor(Executor):
    """Runs tasks here, except that the worker of ``victim`` 'dies'."""

    def __init__(self, victim: str):
        self.victim = victim

    def submit(self, fn, *args, **kwargs):
        fut = Future()
        if str(args[0]).endswith(self.victim):
            fut.set_exception(BrokenProcessPool("worker killed"))
        else:
            fut.set_result(fn(*args, **kwargs))
        return fut


def test_a_dead_worker_fails_its_recording_only(sources, tmp_path):
    paths = [sources / GOOD[0], sources / GOOD[1]]
    out = run_many(paths, ["process"], executor=_DyingExecutor(GOOD[0]), output_dir=tmp_path)
    assert not out[0].success and out[0].error == "worker: BrokenProcessPool: worker killed"
    assert out[1].success


@pytest.mark.parametrize("kwargs, match", [
    ({"steps": ("fuse", "process")}, "order"),
    ({"steps": ("process", "process")}, "distinct"),
    ({"steps": ("track",)}, "subset"),
    ({"steps": ()}, "non-empty"),
    ({"executor": ProcessPoolExecutor, "client": object()}, "not both"),
    ({"options": {"fuse": {"mode": "ml"}}}, "FusionConfig"),
    ({"options": {"process": {"frobnicate": 1}}}, "frobnicate"),
    ({"options": {"process": {"progress": True}}}, "progress"),
    ({"options": {"calibrate": {"max_lag_frames": 3}}, "steps": ("fuse",)}, "not in steps"),
    ({"blas_threads": 0}, "blas_threads"),
])
def test_bad_arguments_raise_validation_error(kwargs, match):
    with pytest.raises(ValidationError, match=match):
        run_many(["a.h5", "b.h5"], **kwargs)


def test_bad_path_lists_raise_validation_error(tmp_path):
    with pytest.raises(ValidationError, match="one path"):
        run_many("a.h5")
    with pytest.raises(ValidationError, match="empty"):
        run_many([])
    with pytest.raises(ValidationError, match="twice"):
        run_many(["a.h5", "./a.h5"])
    with pytest.raises(ValidationError, match="named 'a.h5'"):
        run_many(["x/a.h5", "y/a.h5"], output_dir=tmp_path)
    with pytest.raises(ValidationError, match="n_workers"):
        with local_client(0):
            pass


def test_missing_file_is_a_failed_recording_not_an_exception(tmp_path):
    (s,) = run_many([tmp_path / "nope.h5"], ["fuse"])
    assert not s.success and s.error.startswith("fuse: ") and "nope.h5" in s.error


@pytest.mark.slow
def test_cli_batch_flags_the_corrupt_recording_and_exits_1(sources, tmp_path):
    """The real command line, local Dask cluster of 2 workers."""
    work = tmp_path / "in"
    shutil.copytree(sources, work)
    summary = tmp_path / "summary.json"
    proc = subprocess.run(
        [sys.executable, "-m", "mmsnap_graph.app.cli", "batch", str(work / "*.h5"),
         "--workers", "2", "--steps", "process,calibrate", "--json-out", str(summary)],
        capture_output=True, text=True, timeout=600)
    assert proc.returncode == 1, proc.stderr
    out = proc.stdout
    assert "2 of 3 recording(s) ok, 1 failed" in out
    assert f"FAILED {work / BAD}: process: " in out
    for name in GOOD:
        assert any(line.startswith(name) and " ok " in line for line in out.splitlines())
    rows = json.loads(summary.read_text())
    assert [r["success"] for r in rows] == [True, True, False]
    assert rows[0]["steps_done"] == ["process", "calibrate"]
    assert calibration_json_path(work / GOOD[0]).exists()  # updated in place
    assert "cluster started in " in out and "library loaded as each started" in out


def test_the_preload_hook_loads_what_the_steps_run():
    """``dask_setup`` (Dask's preload of ``mmsnap_graph.app.batch``) imports
    GTSAM, h5py and scikit-learn, which importing the module does not."""
    code = ("import sys\nimport mmsnap_graph.app.batch as b\n"
            "heavy = ('gtsam', 'h5py', 'sklearn')\n"
            "print([m in sys.modules for m in heavy])\n"
            "b.dask_setup(None)\nprint([m in sys.modules for m in heavy])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.split("\n")
    assert out[:2] == ["[False, False, False]", "[True, True, True]"]


@pytest.mark.slow
def test_cli_batch_json_prints_the_summaries_alone(sources, tmp_path):
    """``--json`` prints the JSON on stdout (the words go to stderr), as on
    every verb; ``--json-out`` writes the same to a file."""
    work = tmp_path / "in"
    work.mkdir()
    shutil.copy(sources / GOOD[0], work / GOOD[0])
    out_json = tmp_path / "summary.json"
    proc = subprocess.run(
        [sys.executable, "-m", "mmsnap_graph.app.cli", "batch", str(work / GOOD[0]),
         "--workers", "1", "--steps", "process", "--json", "--json-out", str(out_json)],
        capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    rows = json.loads(proc.stdout)
    assert rows == json.loads(out_json.read_text())
    assert [r["success"] for r in rows] == [True]
    assert "cluster started in " in proc.stderr and f"wrote {out_json}" in proc.stderr


def test_existing_outputs_are_replaced_only_with_overwrite(sources, tmp_path, capsys):
    """Before: a second run silently replaced the calibration JSONs (a
    hand-edited one too) and the copies in output_dir."""
    rec = tmp_path / GOOD[0]
    shutil.copyfile(sources / GOOD[0], rec)
    sidecar = calibration_json_path(rec)
    sidecar.write_text("hand-edited\n")
    before = rec.read_bytes()
    with pytest.raises(ValidationError, match=f"{sidecar} exists .*pass --overwrite"):
        run_many([rec], ["calibrate"])
    assert main(["batch", str(rec), "--steps", "calibrate", "--no-progress"]) == 2
    assert "exists" in capsys.readouterr().err
    out = tmp_path / "out"
    out.mkdir()
    (out / GOOD[0]).write_text("an earlier result\n")
    with pytest.raises(ValidationError, match=f"{out / GOOD[0]} exists"):
        run_many([rec], ["fuse"], output_dir=out)
    assert sidecar.read_text() == "hand-edited\n" and rec.read_bytes() == before
    assert (out / GOOD[0]).read_text() == "an earlier result\n"
    (s,) = run_many([rec], ["calibrate"], overwrite=True)
    assert s.success, s.error
    assert json.loads(sidecar.read_text())["nodes"]
