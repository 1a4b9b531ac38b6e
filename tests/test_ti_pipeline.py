"""TI data through the library: the optional TI fields of a node's RadarConfig
survive an HDF5 round trip (before, the reader dropped them: a raw import read
back used the chirp's start frequency for the wavelength again), and the
pipeline gives the EKF the chain's unambiguous speed."""

import dataclasses

import numpy as np

from mmsnap_graph.data.radar_config import TABLE_I
from mmsnap_graph.io import read_recording, write_recording
from mmsnap_graph.sim import simulate_recording
from mmsnap_graph.sim import CLEAN


def test_ti_radar_fields_round_trip(tmp_path):
    radar = dataclasses.replace(TABLE_I, adc_start_s=6e-6, rx_elevation_half_wl=(0.0, 0.0, 0.0, 0.0),
                                tx_channels=(0, 2, 1), wavelength_reference="band_centre")
    rec = simulate_recording("B", "straight", CLEAN, levels=("centroids",), n_frames=5, seed=1)
    nodes = {n: dataclasses.replace(d, radar=radar) for n, d in rec.nodes.items()}
    rec = dataclasses.replace(rec, nodes=nodes)
    path = write_recording(tmp_path / "ti.h5", rec)
    back = read_recording(path).nodes["S1"].radar
    assert back == radar
    assert back.wavelength_m == radar.wavelength_m != TABLE_I.wavelength_m
    np.testing.assert_array_equal(back.tx_channels, (0, 2, 1))


def test_process_node_wraps_the_ekf_doppler_at_the_chains_unambiguous_speed(monkeypatch):
    """The pipeline hands the chain's unambiguous speed to the EKF (issue 14):
    without it the EKF never wrapped its Doppler innovation."""
    from mmsnap_graph.app import pipeline
    from mmsnap_graph.radar.chain import unambiguous_speed_mps

    seen = {}

    def spy(centroids, config, **kw):
        seen["wrap"] = config.doppler_wrap_mps
        return real(centroids, config, **kw)

    real = pipeline.track_centroids
    monkeypatch.setattr(pipeline, "track_centroids", spy)
    rec = simulate_recording("B", "straight", CLEAN, levels=("cube",), n_frames=2, seed=2)
    node = rec.nodes["S1"]
    pipeline.process_node(node, rec.frame_period_s)
    assert seen["wrap"] == unambiguous_speed_mps(node.radar)
