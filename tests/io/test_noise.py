"""The /noise group (mmsnap_graph.io.noise): what the writer puts in the file,
read back with h5py against docs/FORMAT.md's layout; the reader's errors; the
noise ``mmsnap fuse`` takes from it. (Estimating the noise:
tests/calibration/noise/test_estimate.py.)"""

from __future__ import annotations

import shutil

import h5py
import numpy as np
import pytest

from mmsnap_graph.data.noise import MeasurementNoise, NodeNoiseEstimate, NoiseEstimate
from mmsnap_graph.errors import FileFormatError
from mmsnap_graph.io.noise import (NOISE_GROUP, RangeOffsetAtPoses, noise_for_fusion,
                                   noise_lines, read_noise, read_range_offset, write_noise)
from _cli import noise_block, store_partial_noise

FALLBACK = MeasurementNoise(range_m=0.04, omega_rad=0.7, doppler_mps=0.2)


def _estimate() -> NoiseEstimate:
    """S1 identifies every component; S2 only the range (the others are the fallback's)."""
    s1 = NodeNoiseEstimate(noise=MeasurementNoise(range_m=0.03, omega_rad=0.05, doppler_mps=0.15),
                           identified=(True, True, True), n_residuals=(300, 300, 100),
                           method="network+temporal")
    s2 = NodeNoiseEstimate(noise=MeasurementNoise(range_m=0.06, omega_rad=0.7, doppler_mps=0.2),
                           identified=(True, False, False), n_residuals=(100, 0, 0),
                           method="temporal", reasons=("", "too few frames", "no motion"))
    return NoiseEstimate(nodes={"S1": s1, "S2": s2}, fallback=FALLBACK, method="test",
                         message="hand-made")


@pytest.fixture()
def path(recording_b_file, tmp_path):
    """A copy of the shared two-node recording (S1, S2), without /noise."""
    return shutil.copy(recording_b_file, tmp_path / "rec.h5")


def test_the_group_holds_the_layouts_fields_and_reads_back_equal(path):
    est = _estimate()
    assert read_noise(path) is None
    assert write_noise(path, est) == path
    with h5py.File(path, "r") as f:
        g = f[NOISE_GROUP]
        assert g.attrs["format_version"] == "1.0" and g.attrs["method"] == "test"
        np.testing.assert_array_equal(g.attrs["fallback_sigmas"], [0.04, 0.7, 0.2])
        assert list(g["node_name"].asstr()[()]) == ["S1", "S2"]
        np.testing.assert_array_equal(g["sigmas"][()], [[0.03, 0.05, 0.15], [0.06, 0.7, 0.2]])
        np.testing.assert_array_equal(g["identified"][()], [[1, 1, 1], [1, 0, 0]])
        assert g["n_residuals"].dtype == np.int64
        np.testing.assert_array_equal(g["n_residuals"][()], [[300, 300, 100], [100, 0, 0]])
        assert list(g["reason"].asstr()[()][1]) == ["", "too few frames", "no motion"]
    assert read_noise(path) == est
    # A second write replaces the group; output= writes a copy and leaves the file.
    other = NoiseEstimate(nodes={"S1": est.nodes["S2"], "S2": est.nodes["S1"]}, method="again")
    copy = write_noise(path, other, output=path.with_name("copy.h5"))
    assert read_noise(copy) == other and read_noise(path) == est


def test_a_range_offset_at_fixed_poses_is_stored_with_the_noise(path):
    poses = {"S1": np.zeros(3), "S2": np.array([0.0, 7.0, np.pi])}
    assert read_range_offset(path) is None
    write_noise(path, _estimate(), range_offset=RangeOffsetAtPoses(
        offset_m=0.081, poses=poses, message="range offset at these poses +0.081 m"))
    back = read_range_offset(path)
    assert back.offset_m == 0.081 and back.message.endswith("+0.081 m")
    np.testing.assert_array_equal(back.poses["S2"], poses["S2"])
    assert read_noise(path) == _estimate()
    # Not identified: NaN, read back as NaN; a later noise write without one drops it.
    write_noise(path, _estimate(), range_offset=RangeOffsetAtPoses(offset_m=float("nan"),
                                                                   poses=poses))
    assert np.isnan(read_range_offset(path).offset_m)
    write_noise(path, _estimate())
    assert read_range_offset(path) is None
    with pytest.raises(FileFormatError, match=r"no pose for nodes \['S2'\]"):
        write_noise(path, _estimate(), range_offset=RangeOffsetAtPoses(
            offset_m=0.1, poses={"S1": np.zeros(3)}))
    write_noise(path, _estimate(), range_offset=RangeOffsetAtPoses(offset_m=0.1, poses=poses))
    with h5py.File(path, "a") as f:
        del f[NOISE_GROUP]["range_offset/poses"]
    with pytest.raises(FileFormatError, match="range_offset/poses is missing"):
        read_range_offset(path)


@pytest.mark.parametrize("damage, match", [
    (lambda g: g.attrs.__delitem__("fallback_sigmas"), "attribute 'fallback_sigmas' is missing"),
    (lambda g: g.__delitem__("identified"), "/identified is missing"),
    (lambda g: (g.__delitem__("sigmas"), g.create_dataset("sigmas", data=np.ones((2, 2)))),
     r"/sigmas must have shape \(2, 3\), got \(2, 2\)"),
    (lambda g: g["sigmas"].__setitem__((0, 1), -1.0), "is inconsistent"),
])
def test_a_damaged_group_is_a_format_error_naming_the_field(path, damage, match):
    write_noise(path, _estimate())
    with h5py.File(path, "r+") as f:
        damage(f[NOISE_GROUP])
    with pytest.raises(FileFormatError, match=match) as err:
        read_noise(path)
    assert str(path) in str(err.value)


def test_noise_for_fusion_per_node_pooled_or_the_papers(path):
    noise, text = noise_for_fusion(path, ["S1", "S2"])
    assert noise == MeasurementNoise() and "no /noise group" in text
    est = _estimate()
    write_noise(path, est)
    per_node, text = noise_for_fusion(path, ["S1", "S2"])
    assert per_node == {"S1": est.nodes["S1"].noise, "S2": est.nodes["S2"].noise}
    assert text.startswith("sigmas from /noise (")
    pooled, _ = noise_for_fusion(path, ["S1", "S2"], per_node=False)
    # by hand: residual-count weighted RMS per component; the omega and Doppler
    # of S2 have no residuals, so S1's alone count there
    expected = [np.sqrt((300 * 0.03**2 + 100 * 0.06**2) / 400), 0.05, 0.15]
    np.testing.assert_allclose(pooled.sigmas, expected, rtol=1e-12)
    with pytest.raises(FileFormatError, match=r"has no sigmas for nodes \['S3'\]"):
        noise_for_fusion(path, ["S1", "S3"])


def test_the_printed_noise_is_one_short_line_per_node_with_units_and_reasons(path):
    """Before: one line per node of ~150-250 characters, the whole stored
    reason (with its asides and second clause) inlined for each component."""
    est = store_partial_noise(path)
    _, text = noise_for_fusion(path, ["S1", "S2"])
    assert text.splitlines() == noise_block(text) == noise_lines(est)
    # two nodes with different estimators: each line names its own
    est = NoiseEstimate(nodes={"S1": est.nodes["S1"], "S2": _estimate().nodes["S2"]})
    lines = noise_lines(est)
    assert lines[0].startswith("sigmas from /noise (1-sigma;")
    assert lines[1].endswith("estimated from 397-399 residuals [network+temporal]")
    assert lines[2].endswith("not identified: omega (a), Doppler (b) [temporal]")
    assert lines[3:] == ["  (a) too few frames", "  (b) no motion"]
    # nothing identified on two nodes, for one reason: one note, cut to a line
    why = ("cross-node residuals and the Doppler differences with the target's motion fitted "
           "across the nodes carry 0.3 dof; 12 usable differences")
    none = NodeNoiseEstimate(noise=MeasurementNoise(), identified=(False,) * 3,
                             n_residuals=(0, 0, 0), method="none", reasons=(why,) * 3)
    lines = noise_lines(NoiseEstimate(nodes={"S1": none, "S2": none}))
    assert len(lines) == 4 and all(len(ln) <= 100 for ln in lines), lines
    assert lines[1].endswith("none identified (a)") and lines[2].endswith("none identified (a)")
    assert lines[3].startswith("  (a) cross-node residuals and") and lines[3].endswith("...")
    # pooled for single-noise estimators: one more line, with units
    _, text = noise_for_fusion(path, ["S1", "S2"], per_node=False)
    assert text.splitlines()[-1] == ("  one noise for every node (pooled): "
                                     "range 0.0552 m  omega 0.08 rad  Doppler 0.1 m/s")
