"""Every track-matching threshold of a calibration settable from the ``mmsnap
calibrate`` options and the ``[matching]`` table of ``--config``; ``mmsnap
process --sparse`` and ``[chain.cluster] sparse``. (The thresholds'
effect through ``calibrate_recording``: tests/calibration/test_network.py.)"""

from __future__ import annotations

import re

import numpy as np
import pytest

from mmsnap_graph.app.cli import main
from mmsnap_graph.app.config_file import (
    ProcessConfig,
    matching_config_to_toml,
    read_matching_config,
    read_process_config,
)
from mmsnap_graph.calibration import MatchingOptions
from mmsnap_graph.io import write_recording
from mmsnap_graph.sim import SimulationOptions
from mmsnap_graph.sim import simulate_recording
from mmsnap_graph.sim.real.sparse import sparse_clouds


@pytest.fixture(scope="module")
def rec_path(recording_c_random, tmp_path_factory):
    path = tmp_path_factory.mktemp("calopts") / "rec.h5"
    write_recording(path, recording_c_random)
    return path


def _duration_s(rec) -> float:
    frames = np.concatenate([n.centroids.frame for n in rec.nodes.values()])
    return float(np.ptp(frames) + 1) * rec.frame_period_s


def _cli(capsys, *argv):
    try:
        code = main([str(a) for a in argv])
    except SystemExit as exc:  # argparse: a value of the wrong type or choice
        code = exc.code
    out = capsys.readouterr()
    return code, out.out, out.err


def _error_line(err: str) -> str:
    """The one error line (argparse prints its usage before it)."""
    lines = [ln for ln in err.strip().splitlines() if ": error: " in ln]
    assert len(lines) == 1 and lines[0] == err.strip().splitlines()[-1], err
    return lines[0]


# --- mmsnap calibrate: options and the [matching] table -------------------------------------

def test_options_reach_calibrate_recording(recording_c_random, rec_path, tmp_path, capsys):
    js = tmp_path / "c.json"
    too_long = _duration_s(recording_c_random) + 1.0
    code, _, err = _cli(capsys, "calibrate", rec_path, "--no-write", "--json-out", js,
                        "--method", "pose_graph", "--min-common-s", too_long)
    assert code == 1 and f"min_common_s={too_long:g} s" in err
    code, _, err = _cli(capsys, "calibrate", rec_path, "--no-write", "--json-out", js,
                        "--method", "pose_graph", "--source", "centroids",
                        "--inlier-gate-m", 1e-4, "--min-spread-m", 0.3)
    assert code == 1 and "inlier_gate_m=0.0001 m" in err and "min_spread_m=0.3 m" in err
    code, out, _ = _cli(capsys, "calibrate", rec_path, "--no-write", "--json-out", js,
                        "--method", "pose_graph", "--min-common-s", 0.0)
    assert code == 0 and "ok: " in out


def test_config_file_reaches_calibrate_recording_and_options_win(recording_c_random, rec_path,
                                                                  tmp_path, capsys):
    js = tmp_path / "c.json"
    too_long = _duration_s(recording_c_random) + 1.0
    cfg = tmp_path / "cal.toml"
    cfg.write_text(f"[matching]\nmin_common_s = {too_long}\nmax_lag_s = 0.2\n")
    code, _, err = _cli(capsys, "calibrate", rec_path, "--no-write", "--json-out", js,
                        "--method", "pose_graph", "--config", cfg)
    assert code == 1 and f"min_common_s={too_long:g} s" in err and "max_lag_s=0.2 s" in err
    code, out, _ = _cli(capsys, "calibrate", rec_path, "--no-write", "--json-out", js,
                        "--method", "pose_graph", "--config", cfg, "--min-common-s", 0.5)
    assert code == 0 and "ok: " in out


def test_show_config_prints_the_matching_table_and_reads_back(tmp_path, capsys):
    code, text, _ = _cli(capsys, "calibrate", "--show-config")
    assert code == 0 and "[matching]" in text
    for name in ("max_lag_s = 0.3", "min_common_s = 0.5", "min_spread_m = 0.2",
                 "max_rmse_m = 1.0", "inlier_gate_m = 0.5", "gate_probability = 0.997"):
        assert name in text
    path = tmp_path / "m.toml"
    path.write_text(text)
    assert read_matching_config(path) == MatchingOptions()
    cfg = tmp_path / "c.toml"
    cfg.write_text("[matching]\nmin_common_s = 2\ninlier_gate_m = 0.3\n")
    code, text, _ = _cli(capsys, "calibrate", "--show-config", "--config", cfg,
                         "--inlier-gate-m", "0.25", "--max-rmse", "0.8")
    assert code == 0
    assert "min_common_s = 2.0" in text and "inlier_gate_m = 0.25" in text \
        and "max_rmse_m = 0.8" in text
    assert matching_config_to_toml(read_matching_config(cfg)).count("[matching]") == 1


@pytest.mark.parametrize("argv, option", [
    (["--min-common-s", "-1"], "--min-common-s"),
    (["--min-spread-m", "nan"], "--min-spread-m"),
    (["--inlier-gate-m", "0"], "--inlier-gate-m"),
    (["--gate-probability", "1.5"], "--gate-probability"),
    (["--max-lag-s", "-0.5"], "--max-lag-s"),
    (["--max-rmse", "-1"], "--max-rmse-m"),
    (["--min-common-s", "soon"], "--min-common-s"),
])
def test_bad_options_exit_2_with_one_line_naming_the_option(rec_path, tmp_path, capsys, argv,
                                                            option):
    code, _, err = _cli(capsys, "calibrate", rec_path, "--no-write", "--json-out",
                        tmp_path / "c.json", *argv)
    assert code == 2 and option in _error_line(err)


@pytest.mark.parametrize("text, where", [
    ("[matching]\nmin_common_s = -1\n", "matching"),
    ("[matching]\nmin_comon_s = 1\n", "matching.min_comon_s"),
    ("[matching]\ngate_probability = \"high\"\n", "matching.gate_probability"),
    ("[tracker]\nx = 1\n", "tracker"),
    ("[matching]\nmin_common_s = \n", "line 2"),
])
def test_bad_files_exit_2_naming_the_file_table_and_key(rec_path, tmp_path, capsys, text,
                                                        where):
    cfg = tmp_path / "bad.toml"
    cfg.write_text(text)
    code, _, err = _cli(capsys, "calibrate", rec_path, "--no-write", "--json-out",
                        tmp_path / "c.json", "--config", cfg)
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert str(cfg) in err and where in err, err


def test_process_and_calibrate_share_one_file(tmp_path, capsys):
    cfg = tmp_path / "both.toml"
    cfg.write_text("[chain]\nmin_range_m = 0.5\n[chain.cluster]\nsparse = true\n"
                   "[ekf]\nmax_coast_s = 0.4\n[matching]\nmin_common_s = 1.5\n")
    proc = read_process_config(cfg)
    assert proc.chain.min_range_m == 0.5 and proc.sparse is True and proc.ekf.max_coast_s == 0.4
    assert read_matching_config(cfg) == MatchingOptions(min_common_s=1.5)
    # Both --show-config outputs in one file read back to the same settings.
    _, text_p, _ = _cli(capsys, "process", "--show-config", "--config", cfg)
    _, text_c, _ = _cli(capsys, "calibrate", "--show-config", "--config", cfg)
    both = tmp_path / "again.toml"
    both.write_text(text_p + "\n" + text_c)
    assert read_process_config(both) == proc
    assert read_matching_config(both) == MatchingOptions(min_common_s=1.5)
    # A bad [matching] is calibrate's business: process ignores the table.
    cfg.write_text("[matching]\nmin_common_s = -1\n")
    assert read_process_config(cfg) == ProcessConfig()


# --- mmsnap process --sparse and [chain.cluster] sparse ------------------------------------

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
    code, out, err = _cli(capsys, "process", path, "-o", out_path, "--no-progress", *argv)
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
    code, text, _ = _cli(capsys, "process", "--show-config", "--config", cfg, "--sparse", "on")
    assert code == 0 and "sparse = true" in text
    code, text, _ = _cli(capsys, "process", "--show-config")
    assert 'sparse = "auto"' in text


@pytest.mark.parametrize("value", ['"yes"', "1", '"on"'])
def test_a_bad_sparse_key_exits_2_naming_it(cloud_paths, tmp_path, capsys, value):
    cfg = tmp_path / "p.toml"
    cfg.write_text(f"[chain.cluster]\nsparse = {value}\n")
    code, _, err = _cli(capsys, "process", cloud_paths["sparse"], "-o", tmp_path / "o.h5",
                        "--config", cfg)
    assert code == 2 and "chain.cluster.sparse" in err and str(cfg) in err
    code, _, err = _cli(capsys, "process", "--show-config", "--sparse", "maybe")
    assert code == 2 and "--sparse" in _error_line(err)
