"""``mmsnap process`` (mmsnap_graph/app/commands/process.py)."""

import dataclasses


import pytest

from mmsnap_graph.app.commands.process import HELP_DEFAULTS
from mmsnap_graph.radar.cfar import CfarConfig
from mmsnap_graph.tracking.ekf import EkfConfig
from mmsnap_graph.data.recording import Detections
from mmsnap_graph.app.cli import main
from mmsnap_graph.io import read_recording, write_recording


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


def with_centroids(rec, node_index: int, edit) -> object:
    """``rec`` with node ``node_index``'s centroid columns changed by
    ``edit(range_m, omega_rad, doppler_mps)`` (in place on copies)."""
    name = rec.node_names[node_index]
    c = rec.nodes[name].centroids
    r, w, v = c.range_m.copy(), c.omega_rad.copy(), c.doppler_mps.copy()
    edit(r, w, v)
    d = Detections(frame=c.frame, range_m=r, omega_rad=w, doppler_mps=v, snr_db=c.snr_db,
                   target_id=c.target_id)
    return rec.with_node(dataclasses.replace(rec.nodes[name], centroids=d))


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
    """README.md's command-line tour: the centroid, track and row counts its
    text quotes are what process and fuse print."""
    import re
    import shlex

    from mmsnap_graph.app.cli import main
    from _shared import ROOT

    text = (ROOT / "README.md").read_text()
    block = re.search(r"```bash\n(mmsnap simulate .*?)```", text, flags=re.S).group(1)
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
