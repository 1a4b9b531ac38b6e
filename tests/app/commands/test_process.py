"""``mmsnap process`` (mmsnap_graph/app/commands/process.py)."""

import re


import pytest
import numpy as np

from mmsnap_graph.app.commands.process import HELP_DEFAULTS
from mmsnap_graph.radar.cfar import CfarConfig
from mmsnap_graph.tracking.ekf import EkfConfig
from mmsnap_graph.data.recording import Detections
from mmsnap_graph.app.cli import main
from mmsnap_graph.io import read_recording, write_recording
from mmsnap_graph.sim import SimulationOptions, simulate_recording
from mmsnap_graph.sim.real.sparse import sparse_clouds

from _cli import error_line, run_cli, with_centroids


def test_the_defaults_quoted_in_the_help_are_the_configs():
    assert HELP_DEFAULTS == {"pfa": CfarConfig().pfa, "sigma_a_mps2": EkfConfig().sigma_a_mps2}


def test_process_says_what_its_counts_mean(tmp_path, capsys):
    """One walker: one centroid a frame, several track ids one after another
    (a lost track ends, a new id starts); the output says so with the
    numbers behind it."""
    import numpy as np

    from mmsnap_graph.app.cli import main
    from mmsnap_graph.io import read_recording

    path = tmp_path / "rec.h5"
    assert main(["simulate", "--model", "clean", "-c", "C", "-t", "random", "-n", "200",
                 "--seed", "1", "-l", "centroids", "-o", str(path), "--no-progress"]) == 0
    capsys.readouterr()
    assert main(["process", str(path), "--no-progress"]) == 0
    out = capsys.readouterr().out
    rec = read_recording(path, load_cubes=False)
    for name, node in rec.nodes.items():
        ids, lengths = np.unique(node.tracks.track_id, return_counts=True)
        frames = np.unique(node.centroids.frame).size
        assert f"centroids: {len(node.centroids)} clusters in {frames} frames (one a frame " \
               f"is one person" in out
        assert f"tracks: {ids.size} confirmed EKF track ids (a lost track ends and a new id " \
               f"starts" in out
        assert f"longest {lengths.max()} frames ({lengths.max() * rec.frame_period_s:.1f} s)" \
            in out


def test_process_on_huge_values_finishes(recording_b_file, tmp_path):
    def edit(r, w, v):
        r[9] = 1e300
        v[11] = -1e300

    path = write_recording(tmp_path / "huge.h5",
                           with_centroids(read_recording(recording_b_file), 0, edit))
    assert main(["process", str(path), "--no-progress"]) == 0
    assert read_recording(path).nodes["S1"].tracks is not None


@pytest.mark.slow
def test_the_readme_tour_prints_the_counts_the_readme_quotes(tmp_path, capsys, monkeypatch):
    """The simulated tour (docs/tutorials/simulation.md; it was the README's):
    the centroid, track and row counts its text quotes are what process and
    fuse print."""
    import re
    import shlex

    from mmsnap_graph.app.cli import main
    from _shared import ROOT

    text = (ROOT / "docs" / "tutorials" / "simulation.md").read_text()
    block = re.search(r"```bash\n(?:mkdir -p sim\n)(mmsnap simulate .*?)```", text,
                      flags=re.S).group(1)
    (tmp_path / "sim").mkdir()                   # the block's `mkdir -p sim`
    monkeypatch.chdir(tmp_path)
    printed = ""
    for line in block.splitlines():
        argv = shlex.split(line.split("#")[0])[1:]
        if argv[0] in ("simulate", "process", "calibrate", "fuse"):
            assert main(argv + ["--no-progress"]) == 0, argv
            printed += capsys.readouterr().out
    quote = re.search(r"`process` prints (\d+) centroids per node .*? and (\d+) and (\d+) EKF "
                      r"track ids .*? `fuse` prints (\d+) targets in (\d+)\s+frames: .*? in "
                      r"(\d+) frames the", text, flags=re.S).groups()
    cents, t1, t2, rows, frames, split = quote
    assert f"{cents} centroids, {t1} tracks" in printed, printed
    assert f"{cents} centroids, {t2} tracks" in printed
    assert f"fused {rows} targets in {frames} frames" in printed
    assert f"  {split} frames hold more than one target" in printed


# ``mmsnap process --sparse`` and ``[chain.cluster] sparse``.


@pytest.fixture(scope="module")
def cloud_paths(tmp_path_factory):
    """A dense point cloud (20-40 points per frame) and its sparse thinning
    (2-3 moving points, a quarter of the frames empty), 120 frames at 20 fps."""
    dense = simulate_recording({"S1": (0.0, 0.0, 0.0), "S2": (0.0, 7.0, np.pi)}, "random",
                               SimulationOptions(physics=None, n_targets=2, frame_period_s=0.05),
                               levels=("point_cloud",), n_frames=120, seed=4)
    folder = tmp_path_factory.mktemp("sparse")
    paths = {}
    for name, rec in (("dense", dense), ("sparse", sparse_clouds(dense, seed=4))):
        paths[name] = folder / f"{name}.h5"
        write_recording(paths[name], rec)
    return paths


def _centroids(out: str) -> dict[str, tuple[int, bool]]:
    """node -> (centroids, clustered as sparse) from ``mmsnap process``'s report."""
    rows = re.findall(r"^(\w+): point_cloud: \d+ points, (\d+) centroids.*$", out, re.M)
    return {n: (int(c), "min_samples=1" in line)
            for (n, c), line in zip(rows, [ln for ln in out.splitlines()
                                           if ": point_cloud: " in ln])}


def _process(capsys, path, tmp_path, *argv):
    out_path = tmp_path / f"out{len(list(tmp_path.iterdir()))}.h5"
    code, out, err = run_cli(capsys, "process", path, "-o", out_path, "--no-progress", *argv)
    assert code == 0, err
    return _centroids(out)


def test_sparse_option_switches_the_clustering(cloud_paths, tmp_path, capsys):
    auto_d = _process(capsys, cloud_paths["dense"], tmp_path)
    on_d = _process(capsys, cloud_paths["dense"], tmp_path, "--sparse", "on")
    assert set(auto_d) == {"S1", "S2"}
    for n in auto_d:
        assert not auto_d[n][1] and on_d[n][1]      # auto: dense, not sparse; on: sparse
        assert on_d[n][0] > auto_d[n][0]            # lone points become centroids
    auto_s = _process(capsys, cloud_paths["sparse"], tmp_path)
    off_s = _process(capsys, cloud_paths["sparse"], tmp_path, "--sparse", "off")
    for n in auto_s:
        assert auto_s[n][1] and not off_s[n][1]     # auto detects the sparse cloud
        assert off_s[n][0] < auto_s[n][0]           # DBSCAN's 3-point minimum drops most


def test_sparse_key_in_the_file_and_the_option_wins(cloud_paths, tmp_path, capsys):
    cfg = tmp_path / "p.toml"
    cfg.write_text("[chain.cluster]\nsparse = false\n")
    off = _process(capsys, cloud_paths["sparse"], tmp_path, "--config", cfg)
    assert not any(s for _, s in off.values())
    on = _process(capsys, cloud_paths["sparse"], tmp_path, "--config", cfg, "--sparse", "auto")
    assert all(s for _, s in on.values())
    code, text, _ = run_cli(capsys, "process", "--show-config", "--config", cfg, "--sparse", "on")
    assert code == 0 and "sparse = true" in text
    code, text, _ = run_cli(capsys, "process", "--show-config")
    assert 'sparse = "auto"' in text


@pytest.mark.parametrize("value", ['"yes"', "1", '"on"'])
def test_a_bad_sparse_key_exits_2_naming_it(cloud_paths, tmp_path, capsys, value):
    cfg = tmp_path / "p.toml"
    cfg.write_text(f"[chain.cluster]\nsparse = {value}\n")
    code, _, err = run_cli(capsys, "process", cloud_paths["sparse"], "-o", tmp_path / "o.h5",
                        "--config", cfg)
    assert code == 2 and "chain.cluster.sparse" in err and str(cfg) in err
    code, _, err = run_cli(capsys, "process", "--show-config", "--sparse", "maybe")
    assert code == 2 and "--sparse" in error_line(err)
