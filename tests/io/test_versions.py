"""``format_version`` of the /noise and /fused groups: another major version is
refused naming the group and the version (mmsnap_graph.io.versions)."""

from __future__ import annotations

import h5py
import pytest

from mmsnap_graph.data.noise import MeasurementNoise, NodeNoiseEstimate, NoiseEstimate
from mmsnap_graph.errors import FileFormatError
from mmsnap_graph.fusion import fuse_recording
from mmsnap_graph.io import write_recording
from mmsnap_graph.io.fused import read_fused, write_fused
from mmsnap_graph.io.noise import read_noise, write_noise
from mmsnap_graph.sim import simulate_recording
from mmsnap_graph.sim import SimulationOptions
from _fusion import config


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    rec = simulate_recording("A", "straight", SimulationOptions(physics=None, known_poses=True),
                             levels=("centroids",), n_frames=10, seed=3)
    path = write_recording(tmp_path_factory.mktemp("v") / "rec.h5", rec)
    write_fused(path, fuse_recording(rec, config(), progress=False))
    node = NodeNoiseEstimate(noise=MeasurementNoise(), identified=(1, 1, 1),
                             n_residuals=(10, 10, 10), method="temporal")
    write_noise(path, NoiseEstimate(nodes={n: node for n in rec.nodes},
                                    fallback=MeasurementNoise(), method="temporal", message=""))
    return path


def _with_version(path, tmp_path, group, version):
    out = tmp_path / f"{group}.h5"
    out.write_bytes(path.read_bytes())
    with h5py.File(out, "r+") as f:
        f[group].attrs["format_version"] = version
    return out


@pytest.mark.parametrize("group, read", [("noise", read_noise), ("fused", read_fused)])
def test_another_major_version_is_refused(recording, tmp_path, group, read):
    assert read(recording) is not None
    assert read(_with_version(recording, tmp_path, group, "1.7")) is not None   # a minor one
    with pytest.raises(FileFormatError, match=rf"{group}.h5:/{group} has format_version '2.0'; "
                                              r"this reader reads version 1.x"):
        read(_with_version(recording, tmp_path, group, "2.0"))
    with pytest.raises(FileFormatError, match=r"format_version='two' must look like"):
        read(_with_version(recording, tmp_path, group, "two"))
