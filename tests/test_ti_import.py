"""``mmsnap import`` and the TI samples in data/ti (made by tests/ti_samples.py)."""

import numpy as np
import pytest

from mmsnap_graph.app.cli import main
from mmsnap_graph.data.radar_config import RadarConfig
from mmsnap_graph.io import read_recording, write_dca1000_bin
from mmsnap_graph.io.dca1000 import frame_bytes
from mmsnap_graph.io.ti_cfg import parse_ti_cfg
from mmsnap_graph.io.ti_uart import parse_ti_uart
from ti_samples import DATA, MOUNTS, dca_sample_cubes, main as make_samples, simulated
from mmsnap_graph.sim import CLEAN


@pytest.fixture(scope="module")
def truth():
    return simulated()


def _same_points(got, want, *, atol, snr_atol):
    assert got.frame.tolist() == want.frame.tolist()
    np.testing.assert_allclose(got.range_m, want.range_m, atol=atol)
    np.testing.assert_allclose(got.omega_rad, want.omega_rad, atol=atol)
    np.testing.assert_allclose(got.doppler_mps, want.doppler_mps, atol=atol)
    np.testing.assert_allclose(got.snr_db, want.snr_db, atol=snr_atol)


def _csv_numbers(path):
    lines = path.read_text().splitlines()
    cells = [line.split(",") for line in lines[1:]]
    return lines[0], [c[0] for c in cells], np.array([c[1:] for c in cells], dtype=float)


def test_samples_are_what_the_script_makes(tmp_path):
    """The script makes the committed samples again, to their quantisation: the
    simulator's floats may differ in the last bit between NumPy/SciPy builds,
    which moves an int16 ADC count by one LSB or a CSV's sixth decimal by one."""
    make_samples(tmp_path)
    for name in ("dca1000_small.cfg", "dca1000_fast.cfg", "dca1000_fast.mmwave.json"):
        assert (tmp_path / name).read_text() == (DATA / name).read_text(), name
    for name in ("dca1000_small.bin", "dca1000_fast.bin"):
        made = np.frombuffer((tmp_path / name).read_bytes(), dtype="<i2").astype(int)
        kept = np.frombuffer((DATA / name).read_bytes(), dtype="<i2").astype(int)
        assert made.shape == kept.shape, name
        assert np.max(np.abs(made - kept)) <= 1, name          # one ADC count
        assert np.mean(made != kept) < 1e-3, name
    for name in ("points_sensor_frame.csv", "points_room_frame.csv"):
        head, nodes, values = _csv_numbers(tmp_path / name)
        head0, nodes0, values0 = _csv_numbers(DATA / name)
        assert (head, nodes) == (head0, nodes0), name
        assert values.shape == values0.shape, name
        # the sixth decimal (relative for the 1.7e9 s time stamps)
        assert np.all(np.abs(values - values0) <= 1.5e-6 * np.maximum(1.0, np.abs(values0))), name
    for name in ("oob_uart_S1.bin", "oob_uart_S2.bin"):
        made = parse_ti_uart((tmp_path / name).read_bytes())
        kept = parse_ti_uart((DATA / name).read_bytes())
        assert len((tmp_path / name).read_bytes()) == len((DATA / name).read_bytes()), name
        assert made.points.frame.tolist() == kept.points.frame.tolist(), name
        np.testing.assert_allclose(made.points.points_xyz, kept.points.points_xyz, rtol=1e-6,
                                   atol=1e-6, err_msg=name)    # float32 on the wire
        np.testing.assert_allclose(made.points.snr_db, kept.points.snr_db, atol=0.11)


def test_import_uart_sample(tmp_path, truth, capsys):
    out = tmp_path / "uart.h5"
    rc = main(["import", "ti-uart", "--node", f"S1={DATA / 'oob_uart_S1.bin'}", "--cfg",
               str(DATA / "iwr1843_oob.cfg"), "--mount", "S1=0.8,5", "-o", str(out)])
    assert rc == 0, capsys.readouterr().err
    rec = read_recording(out)
    assert rec.frame_period_s == pytest.approx(0.05)            # from the .cfg
    # float32 positions on the wire, SNR in 0.1 dB steps.
    _same_points(rec.nodes["S1"].point_cloud, truth.nodes["S1"].point_cloud, atol=2e-5,
                 snr_atol=0.051)


@pytest.mark.parametrize("frame", ["sensor", "room"])
def test_import_table_samples(tmp_path, truth, frame, capsys):
    out = tmp_path / "table.h5"
    args = ["import", "table", "--table", str(DATA / f"points_{frame}_frame.csv"),
            "--frame-period", "0.05", "-o", str(out)]
    for name, (height, tilt) in MOUNTS.items():
        args += ["--mount", f"{name}={height},{np.rad2deg(tilt)}"]
    if frame == "room":
        args += ["--room-pose", "S1=0,0,0", "--room-pose", "S2=0,7,180"]
    assert main(args) == 0, capsys.readouterr().err
    rec = read_recording(out)
    assert rec.metadata["frame_clock"] == "time_stamps"
    for name in MOUNTS:
        # Six decimals in the CSV.
        _same_points(rec.nodes[name].point_cloud, truth.nodes[name].point_cloud, atol=2e-5,
                     snr_atol=1e-6)


def test_height_band_drops_floor_and_ceiling(tmp_path, truth, capsys):
    out = tmp_path / "band.h5"
    args = ["import", "table", "--node", f"S1={DATA / 'points_sensor_frame.csv'}",
            "--frame-period", "0.05", "--mount", "S1=0.8,5", "--height-band", "0.5,1.5",
            "-o", str(out)]
    # The table holds two nodes: --node with a multi-node table is a usage error
    # that names the option to use.
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "holds 2 nodes" in err and "import it with --table" in err
    import pandas as pd
    df = pd.read_csv(DATA / "points_sensor_frame.csv")
    one = tmp_path / "s1.csv"
    df[df.node == "S1"].drop(columns="node").to_csv(one, index=False)
    args[3] = f"S1={one}"
    assert main(args) == 0
    kept = len(read_recording(out).nodes["S1"].point_cloud)
    assert 0 < kept < len(truth.nodes["S1"].point_cloud)


ADV = """\
dfeDataOutputMode 3
channelCfg 15 7 0
adcCfg 2 1
adcbufCfg -1 0 1 1 1
profileCfg 0 77 10 2 20 0 0 50 1 8 2000 0 0 30
chirpCfg 0 0 0 0 0 0 0 1
chirpCfg 1 1 0 0 0 0 0 4
chirpCfg 2 2 0 0 0 0 0 2
advFrameCfg 2 0 0 1 0
subFrameCfg 0 0 0 2 4 5 0 1 1 5
subFrameCfg 1 0 0 3 2 5 0 1 1 5
"""


def test_import_dca1000_advanced_frame(tmp_path, capsys):
    cfg = tmp_path / "adv.cfg"
    cfg.write_text(ADV)
    ti = parse_ti_cfg(ADV, board="AWR1843BOOST")
    rng = np.random.default_rng(0)
    cubes = [rng.integers(-500, 500, (3, *c.cube_shape)) + 1j * rng.integers(-500, 500,
                                                                              (3, *c.cube_shape))
             for c in ti.configs]
    parts = []
    for k, (c, cube) in enumerate(zip(ti.configs, cubes)):
        write_dca1000_bin(tmp_path / f"sf{k}.bin", cube, c)
        raw = (tmp_path / f"sf{k}.bin").read_bytes()
        parts.append([raw[f * frame_bytes(c):(f + 1) * frame_bytes(c)] for f in range(3)])
    stream = b"".join(parts[0][f] + parts[1][f] for f in range(3))
    half = len(stream) // 2
    (tmp_path / "adc_data_0.bin").write_bytes(stream[:half])     # split inside a frame
    (tmp_path / "adc_data_1.bin").write_bytes(stream[half:])
    out = tmp_path / "raw.h5"
    base = ["import", "dca1000", "--cfg", str(cfg), "--node",
            f"S1={tmp_path / 'adc_data_0.bin'}", "--node", f"S1={tmp_path / 'adc_data_1.bin'}",
            "-o", str(out)]
    assert main(base + ["--board", "AWR1843BOOST"]) == 2
    assert "choose one with --sub-frame" in capsys.readouterr().err
    assert main(base + ["--sub-frame", "1"]) == 2
    assert "does not say where the antennas are" in capsys.readouterr().err
    assert main(base + ["--board", "AWR1843BOOST", "--sub-frame", "1"]) == 0
    node = read_recording(out).nodes["S1"]
    np.testing.assert_array_equal(node.cube, cubes[1])
    # Firing order TX0, TX2, TX1 on the AWR1843 layout.
    assert node.radar.tx_azimuth_half_wl == (0.0, 4.0, 2.0)
    assert node.radar.tx_elevation_half_wl == (0.0, 0.0, 1.0)
    assert isinstance(node.radar, RadarConfig)


def test_import_argument_errors(tmp_path, capsys):
    out = str(tmp_path / "x.h5")
    assert main(["import", "ti-uart", "--node", f"S1={DATA / 'oob_uart_S1.bin'}", "-o",
                 out]) == 2
    assert "frame period is unknown" in capsys.readouterr().err
    assert main(["import", "table", "--table", str(DATA / "points_sensor_frame.csv"),
                 "--frame-period", "0.05", "--mount", "S9=1,0", "-o", out]) == 2
    assert "not imported" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["import", "table", "--height-band", "1", "-o", out])


@pytest.mark.slow
@pytest.mark.slow
def test_lifted_point_clouds_calibrate_like_the_2d_simulation(tmp_path):
    """simulate (2D) -> lift to tilted, raised 3D sensors -> CSV -> import ->
    process -> calibrate recovers S2's pose as well as the direct 2D path."""
    import pandas as pd
    from mmsnap_graph.io import write_recording
    from mmsnap_graph.sim import simulate_recording
    from ti_samples import lift
    sim = simulate_recording("C", "straight", CLEAN, levels=["point_cloud"], n_frames=300, seed=2)
    mounts = {"S1": (0.8, np.deg2rad(5.0)), "S2": (1.2, np.deg2rad(12.0))}
    rows = []
    for k, (name, node) in enumerate(sim.nodes.items()):
        xyz, dop = lift(node.point_cloud, *mounts[name], seed=k)
        rows.append(pd.DataFrame({"node": name, "frame": node.point_cloud.frame, "x": xyz[:, 0],
                                  "y": xyz[:, 1], "z": xyz[:, 2], "doppler": dop}))
    pd.concat(rows).to_csv(tmp_path / "lifted.csv", index=False, float_format="%.6f")
    write_recording(tmp_path / "direct.h5", sim)
    assert main(["import", "table", "--table", str(tmp_path / "lifted.csv"), "--frame-period",
                 "0.15", "--mount", "S1=0.8,5", "--mount", "S2=1.2,12", "-o",
                 str(tmp_path / "imported.h5")]) == 0
    errors = {}
    for name in ("direct", "imported"):
        path = str(tmp_path / f"{name}.h5")
        assert main(["process", path, "--no-progress"]) == 0
        assert main(["calibrate", path]) == 0
        pose = read_recording(path).nodes["S2"].pose
        true = sim.truth.node_poses["S2"]
        errors[name] = np.hypot(*(pose[:2] - true[:2]))
    # Measured: 0.0095 m direct; the import adds only the CSV's 1e-6 rounding.
    assert errors["direct"] < 0.05
    assert errors["imported"] <= 1.2 * errors["direct"]


def test_destack_and_accumulate_options(tmp_path, capsys):
    import pandas as pd
    pts = pd.DataFrame({"frame": [0, 1, 1, 2, 2], "x": [1, 2, 1, 3, 2], "y": 2.0, "z": 0.0,
                        "doppler": 0.5})                       # stacks of the last 2 frames
    src = tmp_path / "stacked.csv"
    pts.to_csv(src, index=False)
    out = tmp_path / "o.h5"
    base = ["import", "table", "--node", f"S1={src}", "--frame-period", "0.1", "-o", str(out),
            "--overwrite"]
    assert main(base + ["--destack"]) == 0
    assert read_recording(out).nodes["S1"].point_cloud.frame.tolist() == [0, 1, 2]
    assert main(base + ["--destack", "--accumulate", "2"]) == 0
    rec = read_recording(out)
    assert rec.nodes["S1"].point_cloud.frame.tolist() == [0, 1, 1, 2, 2]
    assert rec.metadata["accumulated_frames"] == 2
    assert main(base + ["--accumulate", "0"]) == 2
    assert "n_frames=0" in capsys.readouterr().err


@pytest.mark.parametrize("sub_frame", [0, 1])
def test_import_dca1000_sample(tmp_path, sub_frame, capsys):
    ti, cubes = dca_sample_cubes()
    out = tmp_path / "dca.h5"
    assert main(["import", "dca1000", "--cfg", str(DATA / "dca1000_small.cfg"), "--board",
                 "AWR1843BOOST", "--sub-frame", str(sub_frame), "--node",
                 f"S1={DATA / 'dca1000_small.bin'}", "-o", str(out)]) == 0
    node = read_recording(out).nodes["S1"]
    # The reader is exact: the committed capture decodes to whole ADC counts, and
    # the cube the script simulates here matches them to one count (the last bit
    # of the simulator's floats may differ between NumPy/SciPy builds).
    np.testing.assert_array_equal(node.cube, np.round(node.cube.real) + 1j * np.round(
        node.cube.imag))
    np.testing.assert_allclose(node.cube, cubes[sub_frame], rtol=0, atol=np.sqrt(2))
    assert np.mean(node.cube != cubes[sub_frame]) < 1e-3
    assert node.radar.n_tx == (2, 3)[sub_frame]
    assert "3 cubes" in capsys.readouterr().out
