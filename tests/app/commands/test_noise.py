"""Noise from the data through the command line (issue 11 items 1-2):
`mmsnap calibrate` writes /noise, `mmsnap fuse` uses it (robust by default),
`mmsnap noise` estimates it without calibrating."""

from __future__ import annotations

import argparse
import json
import re

import h5py
import numpy as np
import pytest

from mmsnap_graph.app.cli import main
from mmsnap_graph.app.commands import noise as noise_command
from mmsnap_graph.io import read_fused
from mmsnap_graph.io.noise import read_noise
from mmsnap_graph.sim import CENTROID_NOISE

PAPER = ["0.035", "0.7853981633974483", "0.1807"]
TRUE = [str(v) for v in CENTROID_NOISE.sigmas]          # 0.05 m, 0.08 rad, 0.1 m/s
THREE = ["--node", "S1=0,0,0", "--node", "S2=0,7,180", "--node", "S3=3.5,3.5,90"]
_SIM_KEYS = ("centroid_range_std_m", "centroid_omega_std_rad", "centroid_doppler_std_mps")


def _simulate(path, network, frames, seed, *extra):
    """A simulated recording whose centroid sigmas nobody wrote down: the
    simulator's metadata sigmas are removed (the estimate must come from the
    data)."""
    assert main(["simulate", "--model", "clean", *network, "-l", "centroids", "-n", str(frames), "-s", str(seed),
                 "-o", str(path), "--no-progress", *extra]) == 0
    with h5py.File(path, "r+") as f:
        for k in _SIM_KEYS:
            del f["metadata"].attrs[k]
    assert not np.allclose(CENTROID_NOISE.sigmas, [0.035, np.pi / 4, 0.1807], rtol=0.2)


def _evaluate(path, capsys) -> dict:
    capsys.readouterr()
    assert main(["evaluate", str(path), "--json"]) == 0
    return json.loads(capsys.readouterr().out)["fused"]


@pytest.mark.slow
@pytest.mark.parametrize("network,seed", [
    (["-c", "C"], 1),
    (THREE, 2),
    (["-c", "C", "-t", "random"], 3),
], ids=["2 nodes", "3 nodes", "2 nodes random walk"])
def test_fuse_without_sigmas_is_consistent_on_data_nobody_described(tmp_path, capsys, network,
                                                                    seed):
    """Target of issue 11: calibrate then fuse with no --sigmas: NEES inside
    the 95 % chi-square band and position RMSE within 10 % of fusing with the
    true sigmas; the paper's sigmas on the same data are out of band."""
    rec = tmp_path / "rec.h5"
    _simulate(rec, network, 600, seed)
    assert main(["calibrate", str(rec)]) == 0
    out = capsys.readouterr().out
    assert "NOT identified" not in out and "estimated" in out
    est = read_noise(rec)
    assert est is not None and all(all(e.identified) for e in est.nodes.values())
    for path, extra in ((tmp_path / "true.h5", ["--sigmas", *TRUE]),
                        (tmp_path / "paper.h5", ["--sigmas", *PAPER])):
        assert main(["fuse", str(rec), "-o", str(path), "--no-progress", *extra]) == 0
    assert main(["fuse", str(rec), "--no-progress"]) == 0
    assert "sigmas from /noise" in capsys.readouterr().out
    data, true, paper = (_evaluate(p, capsys) for p in (rec, tmp_path / "true.h5",
                                                         tmp_path / "paper.h5"))
    lo, hi = data["nees"]["interval_95"]
    assert lo < data["nees"]["mean"] < hi, (data["nees"], true["nees"])
    assert data["position_rmse_m"] <= 1.10 * true["position_rmse_m"]
    assert lo < true["nees"]["mean"] < hi
    assert not lo < paper["nees"]["mean"] < hi, paper["nees"]     # the test can fail


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    path = tmp_path_factory.mktemp("noise") / "small.h5"
    _simulate(path, ["-c", "C"], 150, 4, "--known-poses")
    return path


def test_fuse_without_noise_says_it_uses_the_papers_sigmas(tmp_path, capsys, small):
    out = tmp_path / "f.h5"
    assert main(["fuse", str(small), "-o", str(out), "--no-progress"]) == 0
    text = capsys.readouterr().out
    assert "no /noise group" in text and "paper's sigmas" in text
    assert "robust gate" in text
    fused = read_fused(out)
    assert fused.robust == "gate"                              # robust fusion on by default
    np.testing.assert_allclose(fused.noise_sigmas, [0.035, np.pi / 4, 0.1807])
    assert main(["fuse", str(small), "-o", str(out), "--no-progress", "--robust", "none",
                 "--sigmas", *TRUE, "--overwrite"]) == 0
    assert "sigmas from --sigmas" in capsys.readouterr().out
    fused = read_fused(out)
    assert fused.robust is None
    np.testing.assert_allclose(fused.noise_sigmas, CENTROID_NOISE.sigmas)


def _noise_cli(argv) -> int:
    parser = argparse.ArgumentParser(prog="mmsnap")
    noise_command.register(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["noise", *argv])
    return args.func(args)


def test_noise_command_and_sigmas_override(tmp_path, capsys, small):
    copy = tmp_path / "n.h5"
    assert _noise_cli([str(small), "-o", str(copy)]) == 0
    text = capsys.readouterr().out
    assert "6 of 6 node sigmas identified" in text
    # printed as `mmsnap calibrate` prints it: one sigma a line, with its unit
    assert len(re.findall(r"^    (range   [0-9.]+ m|omega   [0-9.]+ rad|doppler [0-9.]+ m/s): "
                          r"estimated from \d+ residuals", text, flags=re.M)) == 6, text
    assert read_noise(small) is None                            # -o left the input alone
    est = read_noise(copy)
    assert est.method == "network+temporal"
    for e in est.nodes.values():
        assert e.method.startswith("network+temporal")
        np.testing.assert_allclose(e.noise.sigmas, CENTROID_NOISE.sigmas, rtol=0.25)
    assert _noise_cli([str(copy), "--no-write", "--method", "temporal"]) == 0
    # the stored noise is used per node; --sigmas wins over it
    out = tmp_path / "f.h5"
    assert main(["fuse", str(copy), "-o", str(out), "--no-progress"]) == 0
    assert "sigmas from /noise" in capsys.readouterr().out
    np.testing.assert_allclose(read_fused(out).noise_sigmas, est.pooled().sigmas)
    assert main(["fuse", str(copy), "-o", str(out), "--no-progress", "--sigmas", *PAPER,
                 "--overwrite"]) == 0
    np.testing.assert_allclose(read_fused(out).noise_sigmas, [0.035, np.pi / 4, 0.1807])


def test_calibrate_no_write_leaves_the_recording_without_noise(tmp_path, capsys, small):
    copy = tmp_path / "c.h5"
    copy.write_bytes(small.read_bytes())
    assert main(["calibrate", str(copy), "--no-write", "--json-out", str(tmp_path / "c.json")]) == 0
    text = capsys.readouterr().out
    assert "measurement noise per node, estimated from the data" in text
    assert read_noise(copy) is None
    assert main(["calibrate", str(copy), "--json-out", str(tmp_path / "c.json"), "--overwrite"]) == 0
    assert read_noise(copy) is not None


def test_noise_at_fixed_poses_takes_the_range_offset_out_first(calibrated_c_file, tmp_path,
                                                               capsys):
    """Before: at the poses of a calibration JSON, centroids 0.08 m short in
    range (a body's near side) made the range sigma about 0.08 m, while
    `mmsnap fuse --calibration` adds the offset it finds there: the depth
    counted twice. Now the noise is estimated on the ranges fuse fuses."""
    from mmsnap_graph.io import read_recording, write_recording

    from _cli import with_centroids

    rec = read_recording(calibrated_c_file, load_cubes=False)
    true_json = tmp_path / "true.json"
    true_json.write_text(json.dumps({"nodes": {n: {"pose": [float(v) for v in p]}
                                               for n, p in rec.truth.node_poses.items()}}))
    plain = write_recording(tmp_path / "plain.h5", rec)
    for i in range(len(rec.node_names)):
        rec = with_centroids(rec, i, lambda r, w, v: r.__isub__(0.08))
    short = write_recording(tmp_path / "short.h5", rec)
    sig = {}
    for path in (plain, short):
        capsys.readouterr()
        assert main(["noise", str(path), "--calibration", str(true_json)]) == 0
        sig[path] = np.array([e.noise.range_m for e in read_noise(path).nodes.values()])
    found = re.search(r"range offset at these poses ([+-][0-9.]+)", capsys.readouterr().out)
    assert found and abs(float(found.group(1)) - 0.08) < 0.015, found
    np.testing.assert_allclose(sig[short], sig[plain], rtol=0.1)


def test_a_calibration_json_without_a_node_is_refused(tmp_path, capsys, small):
    """Before: noise --calibration with a JSON lacking S2 fell back to the
    temporal estimate of every node, silently (fuse refuses the file)."""
    import json

    poses = tmp_path / "s1_only.json"
    poses.write_text(json.dumps({"nodes": {"S1": {"pose": [0.0, 0.0, 0.0]}}}))
    assert main(["noise", str(small), "--no-write", "--calibration", str(poses)]) == 1
    assert "has no pose for node(s) ['S2']" in capsys.readouterr().err


def test_a_stored_noise_is_replaced_only_with_overwrite(tmp_path, capsys, small):
    """Before: `mmsnap noise REC` replaced the /noise that `mmsnap calibrate`
    stored (and `mmsnap fuse` uses) without a word, although the verb has
    --overwrite. Now it refuses (exit 2, nothing written) unless told."""
    rec = tmp_path / "n.h5"
    rec.write_bytes(small.read_bytes())
    assert main(["noise", str(rec)]) == 0                     # no /noise yet: written
    with h5py.File(rec, "r+") as f:                           # mark the stored group
        f["noise"].attrs["marker"] = "stored"
    capsys.readouterr()
    assert main(["noise", str(rec), "--method", "temporal"]) == 2
    err = capsys.readouterr().err
    assert "already holds a /noise group" in err and "--overwrite" in err
    with h5py.File(rec, "r") as f:
        assert f["noise"].attrs["marker"] == "stored"
        assert f["noise"].attrs["method"] == "network+temporal"
    assert main(["noise", str(rec), "--no-write"]) == 0        # printing only is fine
    copy = tmp_path / "copy.h5"
    assert main(["noise", str(rec), "-o", str(copy)]) == 0     # so is a copy
    assert main(["noise", str(rec), "--method", "temporal", "--overwrite"]) == 0
    with h5py.File(rec, "r") as f:
        assert "marker" not in f["noise"].attrs
    assert read_noise(rec).method == "temporal"
