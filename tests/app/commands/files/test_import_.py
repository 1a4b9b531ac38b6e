"""``mmsnap import``: unit mistakes, frame clocks that disagree, and messages
that name the command-line options."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, strategies as st

from mmsnap_graph.app.cli import main
from mmsnap_graph.io import read_recording, write_dca1000_bin, read_fused, write_recording
from mmsnap_graph.sim import CLEAN
from mmsnap_graph.data.radar_config import RadarConfig
from mmsnap_graph.io.ti.dca1000 import frame_bytes
from mmsnap_graph.io.ti.cfg import parse_ti_cfg
from mmsnap_graph.app.evaluation import evaluate_recording

from _shared import DATA, TI_DATA, csv_lines, replace_cell
from _fuzz import CLI_FUZZ, one_line_data_error
from ti_samples import (
    MOUNTS,
    dca_sample_cubes,
    simulated,
    FRAME_PERIOD_S,
    table_rows,
    write_uart_log,
)

SENSOR_CSV = TI_DATA / "points_sensor_frame.csv"
#: The real recordings' point tables (data/real/darksz/README.md: room frame, 20 fps).
REAL = DATA / "real" / "darksz"
#: How data/real/darksz/README.md imports the multiple-tracking recording.
REAL_MOUNTING = ("--frame-period", "0.05", "--mount", "S1=0.8,0", "--mount", "S2=1.1,0",
                 "--height-band", "0.2,2.0")


def _real_table(tmp_path, node="S1", change=None, header=None, name=None):
    """A real table (multiple tracking) with ``change(cells)`` applied to each
    row (the columns frame, time_s, x_m, y_m, z_m, doppler_mps, snr_db) and
    ``header`` in place of its header line."""
    lines = (REAL / f"multiple_tracking_{node}.csv").read_text().splitlines()
    rows = [line.split(",") for line in lines[1:]]
    if change is not None:
        rows = [change(cells) for cells in rows]
    path = tmp_path / (name or f"{node}.csv")
    path.write_text("\n".join([header or lines[0]] + [",".join(r) for r in rows]) + "\n")
    return path


def _import_table(tmp_path, *extra, table=SENSOR_CSV):
    return main(["import", "table", "--table", str(table), "-o", str(tmp_path / "o.h5"),
                 "--overwrite", *extra])


def _sample_with(tmp_path, change, name="edited.csv"):
    """The sensor-frame sample with ``change(header, cells)`` applied to each row."""
    lines = SENSOR_CSV.read_text().splitlines()
    header = lines[0].split(",")
    rows = [change(header, line.split(",")) for line in lines[1:]]
    path = tmp_path / name
    path.write_text("\n".join([",".join(header)] + [",".join(r) for r in rows]) + "\n")
    return path


@pytest.mark.parametrize("period, words", [("50", "milliseconds? (50 ms is --frame-period 0.05)"),
                                           ("1e-300", "below any TI radar's")])
def test_frame_period_in_the_wrong_unit(tmp_path, capsys, period, words):
    assert _import_table(tmp_path, "--frame-period", period) == 2
    err = capsys.readouterr().err
    assert "--frame-period" in err and words in err


def test_frame_period_that_disagrees_with_the_stamps(tmp_path, capsys):
    """The sample is 20 fps: 0.1 s would merge frames in pairs."""
    assert _import_table(tmp_path, "--frame-period", "0.1") == 2
    err = capsys.readouterr().err
    assert "--frame-period=0.1 s disagrees with the time stamps, which advance 0.05 s" in err
    assert _import_table(tmp_path, "--frame-period", "0.05") == 0


def test_stamps_coarser_than_a_frame(tmp_path, capsys):
    """Time stamps rounded to whole seconds would merge 20 frames into one."""
    def whole_seconds(header, cells):
        k = header.index("time_s")
        cells[k] = f"{np.floor(float(cells[k])):.0f}"
        return cells
    path = _sample_with(tmp_path, whole_seconds)
    assert _import_table(tmp_path, "--frame-period", "0.05", table=path) == 2
    err = capsys.readouterr().err
    assert "disagrees with the time stamps" in err and "coarser than a frame" in err


def test_period_merging_stamps_of_a_table_without_frames(tmp_path, capsys):
    def no_frame(header, cells):
        return [c for h, c in zip(header, cells) if h != "frame"]
    path = _sample_with(tmp_path, no_frame)
    lines = path.read_text().splitlines()
    lines[0] = ",".join(h for h in lines[0].split(",") if h != "frame")
    path.write_text("\n".join(lines) + "\n")
    assert _import_table(tmp_path, "--frame-period", "1.0", table=path) == 2
    assert "--frame-period=1 s merges distinct time stamps 0.05 s apart" in \
        capsys.readouterr().err
    assert _import_table(tmp_path, "--frame-period", "0.05", table=path) == 0


def test_real_stamps_in_milliseconds_name_the_time_unit(tmp_path, capsys):
    """Relative stamps in ms without a frame column were read as seconds:
    frames 0-643000 (32150 s), then no centroid; now a unit error."""
    to_ms = lambda c: [str(int(c[0]) * 50)] + c[2:]       # time in ms, no frame column
    paths = [_real_table(tmp_path, node, to_ms, header="time,x,y,z,doppler,snr")
             for node in ("S1", "S2")]
    argv = ["import", "table", "--node", f"S1={paths[0]}", "--node", f"S2={paths[1]}",
            *REAL_MOUNTING, "--room-pose", "S1=0,0,0", "--room-pose", "S2=1.7,1.65,90",
            "-o", str(tmp_path / "ms.h5")]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "a median 1000 frames" in err and "give --time-unit ms" in err
    assert main(argv + ["--time-unit", "ms"]) == 0
    assert "S2: 3346 points in 642 frames" in capsys.readouterr().out


def _real_spherical_degrees(tmp_path, node, room_pose_deg, height_m):
    """A real table taken back to its sensor frame, as TI's spherical points
    (range, azimuth, elevation) in degrees."""
    from factors.projection import cartesian_to_spherical, room_to_sensor
    table = np.genfromtxt(REAL / f"multiple_tracking_{node}.csv", delimiter=",", names=True)
    pose = [room_pose_deg[0], room_pose_deg[1], np.deg2rad(room_pose_deg[2])]
    xyz = room_to_sensor(np.column_stack([table["x_m"], table["y_m"], table["z_m"]]), pose,
                         height_m, 0.0)
    r, az, el = cartesian_to_spherical(xyz)
    rows = [f"{int(f)},{a:.6f},{b:.4f},{c:.4f},{v}" for f, a, b, c, v in
            zip(table["frame"], r, np.degrees(az), np.degrees(el), table["doppler_mps"])]
    path = tmp_path / f"spherical_{node}.csv"
    path.write_text("\n".join(["frame,range,azimuth,elevation,doppler", *rows]) + "\n")
    return path


def test_real_spherical_angles_in_degrees_need_the_flag(tmp_path, capsys):
    """Degrees read as radians were accepted (calibrate then failed about target
    ids); an angle beyond +-pi is now an error naming --degrees."""
    s1 = _real_spherical_degrees(tmp_path, "S1", (0, 0, 0), 0.8)
    s2 = _real_spherical_degrees(tmp_path, "S2", (1.7, 1.65, 90), 1.1)
    argv = ["import", "table", "--node", f"S1={s1}", "--node", f"S2={s2}", *REAL_MOUNTING,
            "-o", str(tmp_path / "sph.h5")]
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert "beyond +-pi: not an angle in radians; degrees?" in err and "--degrees" in err
    assert main(argv + ["--degrees"]) == 0
    out, err = capsys.readouterr()
    assert "S2: 3346 points in 642 frames" in out and "warning" not in err


def test_real_snr_in_tenths_of_a_db_is_named(tmp_path, capsys):
    """TI's side info counts 0.1 dB: read as dB, SNRs of 112-512 'dB' were kept
    without a word; now an error naming --snr-unit."""
    tenths = lambda c: c[:6] + [f"{float(c[6]) * 10:.0f}"]
    path = _real_table(tmp_path, "S1", tenths)
    argv = ["import", "table", "--node", f"S1={path}", "--frame-period", "0.05", "-o",
            str(tmp_path / "snr.h5")]
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert "column snr holds SNRs up to 512 dB (median 182 dB)" in err
    assert "--snr-unit 0.1db" in err
    assert main(argv + ["--snr-unit", "0.1db"]) == 0
    snr = read_recording(tmp_path / "snr.h5").nodes["S1"].point_cloud.snr_db
    assert 11 <= np.nanmin(snr) and np.nanmax(snr) <= 52


def _real_in_format(tmp_path, node, kind):
    """The real table of ``node`` as a TI tool or a spreadsheet writes it."""
    import json
    rows = [line.split(",") for line in
            (REAL / f"multiple_tracking_{node}.csv").read_text().splitlines()[1:]]
    stamp = lambda cells: f"{1.7e12 + 50 * int(cells[0]):.1f}"        # the host's ms clock
    if kind == "replay":
        frames: dict = {}
        for c in rows:
            frames.setdefault(int(c[0]), []).append([float(v) for v in c[2:7]] + [60.0, 255])
        data = [{"frameData": {"frameNum": k, "pointCloud": frames.get(k, [])},
                 "timestamp": 1.7e12 + 50.0 * k} for k in range(max(frames) + 1)]
        path = tmp_path / f"replay_{node}.json"
        cfg = [line + "\n" for line in (TI_DATA / "iwr1843_oob.cfg").read_text().splitlines()]
        path.write_text(json.dumps({"cfg": cfg, "demo": "SDK Out of Box Demo", "data": data}))
        return path
    header, sep, cells = {
        "units": ("Frame Number,Timestamp (ms),X (m),Y (m),Z (m),Doppler (m/s),SNR (dB),"
                  "Noise (dB)", ",", lambda c: [c[0], stamp(c), *c[2:], "60.0"]),
        "visualizer": ("frameNum,timestamp,X,Y,Z,Doppler,SNR,Noise,Track index", ",",
                       lambda c: [c[0], stamp(c), *c[2:], "60.0", "255"]),
        "tsv": ("frame\ttime_s\tx_m\ty_m\tz_m\tdoppler_mps\tsnr_db", "\t", lambda c: c),
        "semicolon": ("frame;time_s;x_m;y_m;z_m;doppler_mps;snr_db", ";",
                      lambda c: [v.replace(".", ",") for v in c]),
    }[kind]
    path = tmp_path / f"{kind}_{node}.csv"
    path.write_text("\n".join([header] + [sep.join(cells(c)) for c in rows]) + "\n")
    return path


@pytest.mark.parametrize("kind, extra", [("units", []), ("replay", []),
                                         ("visualizer", ["--columns", "visualizer"]),
                                         ("tsv", []), ("semicolon", [])])
def test_real_tables_in_ti_tools_formats(tmp_path, capsys, kind, extra):
    """A visualizer's CSV ("X (m)", "Doppler (m/s)") failed with 'missing
    columns'; its replay JSON, a TSV or a semicolon CSV with a garbled message.
    Each now imports the real recording's points exactly."""
    paths = {node: _real_in_format(tmp_path, node, kind) for node in ("S1", "S2")}
    room = ["--room-pose", "S1=0,0,0", "--room-pose", "S2=1.7,1.65,90"]
    base = ["import", "table", *REAL_MOUNTING, *room, "--overwrite"]
    assert main(base + ["--node", f"S1={REAL / 'multiple_tracking_S1.csv'}", "--node",
                        f"S2={REAL / 'multiple_tracking_S2.csv'}", "-o",
                        str(tmp_path / "ref.h5")]) == 0
    assert main(base + ["--node", f"S1={paths['S1']}", "--node", f"S2={paths['S2']}", *extra,
                        "-o", str(tmp_path / "o.h5")]) == 0
    assert "S2: 3346 points in 642 frames" in capsys.readouterr().out
    ref, got = read_recording(tmp_path / "ref.h5"), read_recording(tmp_path / "o.h5")
    for node in ("S1", "S2"):
        a, b = ref.nodes[node].point_cloud, got.nodes[node].point_cloud
        np.testing.assert_array_equal(a.frame, b.frame)
        np.testing.assert_array_equal(a.range_m, b.range_m)
        np.testing.assert_array_equal(a.omega_rad, b.omega_rad)
        np.testing.assert_array_equal(a.snr_db, b.snr_db)


def test_a_replay_files_cfg_lines_give_the_frame_period(tmp_path, capsys):
    """The visualizer stores the .cfg it sent: no --frame-period is needed."""
    paths = [_real_in_format(tmp_path, node, "replay") for node in ("S1", "S2")]
    assert main(["import", "table", "--node", f"S1={paths[0]}", "--node", f"S2={paths[1]}",
                 "--mount", "S1=0.8,0", "--mount", "S2=1.1,0", "--room-pose", "S1=0,0,0",
                 "--room-pose", "S2=1.7,1.65,90", "-o", str(tmp_path / "o.h5")]) == 0
    out = capsys.readouterr().out
    assert f"frame period 0.05 s: the .cfg lines of {paths[0]}" in out
    assert read_recording(tmp_path / "o.h5").frame_period_s == 0.05


def test_a_visualizer_table_without_the_preset_names_it(tmp_path, capsys):
    path = _real_in_format(tmp_path, "S1", "visualizer")
    assert main(["import", "table", "--node", f"S1={path}", "--frame-period", "0.05",
                 "-o", str(tmp_path / "o.h5")]) == 1
    err = capsys.readouterr().err
    assert "--time-unit ms, or --columns visualizer" in err
    with pytest.raises(SystemExit):
        main(["import", "table", "--node", f"S1={path}", "--columns", "visualiser",
              "--frame-period", "0.05", "-o", str(tmp_path / "o.h5")])
    assert "must look like HEADER=COLUMN or be a preset of TI's tools: ['sdk-script', " \
           "'visualizer']" in capsys.readouterr().err
    assert main(["import", "table", "--node", f"S1={path}", "--columns", "visualizer",
                 "--columns", "X=x", "--frame-period", "0.05", "-o", str(tmp_path / "o.h5")]) == 2
    assert "a preset names every column; give it alone" in capsys.readouterr().err


@pytest.mark.parametrize("heading, words", [
    ("180", "heading 180 deg; --room-pose); a radar sees only in front of it: the heading is "
            "the direction of the antenna array axis, the boresight heading + 90 deg; heading "
            "90 deg puts 99.9% in front"),
    ("1.5708", "heading 90 deg (the 1.571 given, read as radians) puts 99.9% in front"),
])
def test_real_room_pose_with_the_boresight_or_in_radians(tmp_path, capsys, heading, words):
    """The boresight heading (180) given where the array axis's (90) is meant
    ended in 'no pair of nodes shares a matched track'; radians (1.5708)
    calibrated S2 at -0.28 deg against a nominal 90, reported 'ok'. Both put
    S2's points beside the radar: an error saying which heading fits."""
    argv = ["import", "table", "--node", f"S1={REAL / 'multiple_tracking_S1.csv'}", "--node",
            f"S2={REAL / 'multiple_tracking_S2.csv'}", *REAL_MOUNTING, "--room-pose", "S1=0,0,0",
            "--room-pose", f"S2=1.7,1.65,{heading}", "-o", str(tmp_path / "o.h5")]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "node S2: " in err and words in err
    assert ("looks like radians" in err) == (heading == "1.5708")


def test_real_room_frame_with_a_room_pose_for_one_node_warns(tmp_path, capsys):
    """A forgotten --room-pose S2 gave a pose with 7 cm sigma and no word."""
    argv = ["import", "table", "--node", f"S1={REAL / 'multiple_tracking_S1.csv'}", "--node",
            f"S2={REAL / 'multiple_tracking_S2.csv'}", *REAL_MOUNTING, "--room-pose", "S1=0,0,0",
            "-o", str(tmp_path / "o.h5")]
    assert main(argv) == 0
    assert "mmsnap import: warning: nodes ['S1'] have a room pose, ['S2'] not" in \
        capsys.readouterr().err


def test_the_nominal_poses_given_are_stored(tmp_path):
    """--room-pose and --pose are what `mmsnap calibrate` compares its poses
    with (--pose wins where both are given)."""
    from mmsnap_graph.evaluation.nominal import nominal_poses
    out = tmp_path / "o.h5"
    assert _import_table(tmp_path, "--frame-period", "0.05", "--mount", "S1=0.8,5", "--mount",
                         "S2=1.2,15", "--pose", "S2=0.1,6.9,179") == 0
    nominal = nominal_poses(read_recording(out).metadata)
    assert list(nominal) == ["S2"] and nominal["S2"].source == "pose"
    np.testing.assert_allclose(nominal["S2"].pose, [0.1, 6.9, np.deg2rad(179)])
    room = TI_DATA / "points_room_frame.csv"
    assert _import_table(tmp_path, "--frame-period", "0.05", "--mount", "S1=0.8,5", "--mount",
                         "S2=1.2,15", "--room-pose", "S1=0,0,0", "--room-pose", "S2=0,7,180",
                         "--pose", "S1=0,0,0", table=room) == 0
    nominal = nominal_poses(read_recording(out).metadata)
    assert {n: p.source for n, p in nominal.items()} == {"S1": "pose", "S2": "room_pose"}


def test_huge_time_stamp_is_a_clear_error(tmp_path, capsys):
    def huge(header, cells):
        if cells[header.index("frame")] == "7":
            cells[header.index("time_s")] = "1e308"
        return cells
    assert _import_table(tmp_path, "--frame-period", "0.05",
                         table=_sample_with(tmp_path, huge)) == 1
    err = capsys.readouterr().err
    assert "column time_s holds 1e+308 s at line" in err and "Traceback" not in err


@pytest.mark.parametrize("mount, words", [("S1=80,5", "80 cm is --mount S1=0.8,5"),
                                          ("S1=0.8,95", "must lie in (-90, 90)")])
def test_mount_in_the_wrong_unit(tmp_path, capsys, mount, words):
    assert _import_table(tmp_path, "--frame-period", "0.05", "--mount", mount) == 2
    err = capsys.readouterr().err
    assert f"--mount {mount}" in err and words in err


def test_gui_headers_with_a_columns_mapping(tmp_path, capsys):
    path = tmp_path / "gui.csv"
    rows = [f"{f},{0.5 + 0.01 * f},{2.0 + 0.01 * k},0.2,0.4" for f in range(20) for k in range(3)]
    path.write_text("\n".join(["Frame,X [m],Y [m],Z [m],Velocity [m/s]", *rows]) + "\n")
    args = ["import", "table", "--node", f"S1={path}", "--frame-period", "0.05", "-o",
            str(tmp_path / "gui.h5")]
    assert main(args) == 0                       # the units in the headers are read
    assert len(read_recording(tmp_path / "gui.h5").nodes["S1"].point_cloud) == 60
    assert main(args + ["--overwrite", "--columns", "X [m]=x", "--columns", "Y [m]=y",
                        "--columns", "Z [m]=z", "--columns", "Velocity [m/s]=doppler"]) == 0
    assert len(read_recording(tmp_path / "gui.h5").nodes["S1"].point_cloud) == 60
    path.write_text(path.read_text().replace("Velocity [m/s]", "Speed [m/s]"))
    assert main(args + ["--overwrite"]) == 1
    err = capsys.readouterr().err
    assert "missing columns" in err and "'Speed [m/s]'" in err and "--columns 'HEADER=x'" in err


def test_unknown_cfg_command_names_the_flag(tmp_path, capsys):
    cfg = tmp_path / "new_sdk.cfg"
    cfg.write_text((TI_DATA / "iwr1843_oob.cfg").read_text() + "shinyNewCmd 1 2 3\n")
    args = ["import", "ti-uart", "--cfg", str(cfg), "--node",
            f"S1={TI_DATA / 'oob_uart_S1.bin'}", "-o", str(tmp_path / "u.h5")]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "unknown command 'shinyNewCmd'" in err and "--ignore-unknown-commands" in err
    assert main(args + ["--ignore-unknown-commands"]) == 0
    assert "ignored unknown commands shinyNewCmd (line" in capsys.readouterr().err


def test_accumulate_survives_the_time_stamp_clock(tmp_path):
    """Accumulated points keep their new frame on a recording clocked by the
    stamps (before, the stamps put every copy back into its original frame)."""
    assert _import_table(tmp_path, "--frame-period", "0.05") == 0
    one = read_recording(tmp_path / "o.h5").nodes["S1"].point_cloud
    assert _import_table(tmp_path, "--frame-period", "0.05", "--accumulate", "3") == 0
    three = read_recording(tmp_path / "o.h5").nodes["S1"].point_cloud
    for f in (30, 31, 60):
        want = sum(np.sum(one.frame == f - lag) for lag in range(3))
        assert np.sum(three.frame == f) == want


@pytest.mark.parametrize("option", [
    ["--frame-period", "nan"], ["--frame-period", "inf"], ["--frame-period", "-1"],
    ["--frame-period", "0"], ["--frame-period", "1e308"], ["--frame-period", "0.05",
                                                           "--accumulate", "100000"],
    ["--frame-period", "0.05", "--accumulate", "-5"],
    ["--frame-period", "0.05", "--height-band", "1,0"],
    ["--frame-period", "0.05", "--height-band", "nan,1"],
    ["--frame-period", "0.05", "--mount", "S1=nan,5"],
    ["--frame-period", "0.05", "--mount", "S1=inf,5"],
    ["--frame-period", "0.05", "--mount", "S3=0.8,5"],
    ["--frame-period", "0.05", "--room-pose", "S1=nan,0,0"],
    ["--frame-period", "0.05", "--columns", "=x"],
    ["--frame-period", "0.05", "--columns", "nothere=x"],
    ["--frame-period", "0.05", "--columns", "x=notacolumn"],
    ["--frame-period", "0.05", "--time-unit", "ms"],
])
def test_odd_option_values_are_one_line_errors(tmp_path, capsys, option):
    """Each is a usage (2) or data (1) error in one line, without a traceback
    (--accumulate 100000 asked for 180 million points: a MemoryError)."""
    try:
        code = _import_table(tmp_path, *option)
    except SystemExit as exc:              # argparse's own usage errors
        code = exc.code
    err = capsys.readouterr().err
    assert code in (1, 2), err
    assert "Traceback" not in err and err.strip(), err
    expected = {"100000": "--accumulate 100000: n_frames=100000 would make 1828 x 100000",
                "ms": "a factor of 0.001: a unit mistake in the time stamps or the frame period?"}.get(option[-1])
    assert expected is None or expected in err, err


# Fuzzing: a damaged UART log or table exits 0 or 1, with one line naming
# the file (never a traceback, never exit 2).


UART = (TI_DATA / "oob_uart_S1.bin").read_bytes()


CSV_LINES = (TI_DATA / "points_sensor_frame.csv").read_text().splitlines()


@CLI_FUZZ
@given(cut=st.integers(0, len(UART)), flips=st.lists(
    st.tuples(st.integers(0, len(UART) - 1), st.integers(0, 7)), max_size=4),
    magic=st.booleans())
def test_import_of_a_damaged_uart_log_exits_0_or_1(tmp_path_factory, capsys, cut, flips, magic):
    d = tmp_path_factory.mktemp("uart")
    data = bytearray(UART[:cut])
    for at, bit in flips:
        if at < len(data):
            data[at] ^= 1 << bit
    if magic and len(data) >= 8:
        data[:8] = b"\x00" * 8  # the first packet's magic word destroyed
    log = d / "log.bin"
    log.write_bytes(bytes(data))
    code = main(["import", "ti-uart", "--node", f"S1={log}", "--frame-period", "0.1",
                 "-o", str(d / "out.h5")])
    err = [line for line in capsys.readouterr().err.strip().splitlines()
           if ": error: " in line or "Traceback" in line]
    if code == 0:
        assert (d / "out.h5").exists() and not err
        return
    one_line_data_error(code, err, "log.bin")
    assert not (d / "out.h5").exists()


@CLI_FUZZ
@given(keep=st.lists(st.sampled_from(["frame", "time_s", "x", "y", "z", "doppler", "snr"]),
                     unique=True, max_size=7),
       rows_=st.integers(0, 40), garbage=st.booleans())
def test_import_of_a_table_with_missing_columns_exits_0_or_1(tmp_path_factory, capsys, keep,
                                                             rows_, garbage):
    d = tmp_path_factory.mktemp("table")
    header = CSV_LINES[0].split(",")
    idx = [header.index(c) for c in keep]
    lines = [",".join(keep)]
    for line in CSV_LINES[1:1 + rows_]:
        if not line.startswith("S1,"):
            continue
        values = line.split(",")
        lines.append(",".join("x!" if garbage and i == 0 else values[j]
                              for i, j in enumerate(idx)))
    table = d / "t.csv"
    table.write_text("\n".join(lines) + "\n")
    code = main(["import", "table", "--node", f"S1={table}", "--frame-period", "0.05",
                 "-o", str(d / "out.h5")])
    err = capsys.readouterr().err.strip().splitlines()
    if code == 0:
        assert {"x", "y", "z", "doppler"} <= set(keep) or {"x", "y", "doppler"} <= set(keep)
        return
    one_line_data_error(code, err, "t.csv")


# Bad TI inputs: one line naming the file and the line (CSV) or the packet
# and frame (UART).


SENSOR_LINES = (TI_DATA / "points_sensor_frame.csv").read_text().splitlines()


def test_the_cli_reports_the_line_in_one_line(tmp_path, capsys):
    lines = list(SENSOR_LINES[:30])
    lines[20] = replace_cell(lines[20], 6, "fast")               # doppler of line 21
    path = csv_lines(tmp_path, lines, "bad.csv")
    assert main(["import", "table", "--table", str(path), "--frame-period", "0.05", "-o",
                 str(tmp_path / "out.h5")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "bad.csv" in err[0] and "line 21 holds 'fast'" in err[0]
    assert not (tmp_path / "out.h5").exists()


def test_a_damaged_uart_log_keeps_its_good_frames_and_names_the_bad_ones(tmp_path, capsys):
    data = bytearray((TI_DATA / "oob_uart_S1.bin").read_bytes())
    second = data.find(b"\x02\x01\x04\x03\x06\x05\x08\x07", 8)     # the second packet
    data[second:second + 8] = b"\x00" * 8                            # its magic word lost
    data = data[:-100]                                               # the last one cut short
    log = tmp_path / "S1.bin"
    log.write_bytes(bytes(data))
    assert main(["import", "ti-uart", "--node", f"S1={log}", "--frame-period", "0.05", "-o",
                 str(tmp_path / "u.h5")]) == 0
    out = capsys.readouterr()
    assert "98 frames" in out.out                                    # 100 - 2 bad ones
    err = out.err.strip().splitlines()
    # Each bad stretch names its packet, the frame number of its header when it
    # has one, and its byte offset (before: "skipped packet 0 at byte 480" for
    # the bytes after packet 0, which was kept, and no frame numbers).
    assert err[0] == ("S1: skipped 480 bytes without a magic word at byte 480, after packet 0 "
                      "(frame 1)")
    assert err[1].startswith("S1: skipped packet 98 (frame 100) at byte 45920: truncated")


# The TI samples in data/ti (made by tests/ti_samples.py) through ``mmsnap import``.


@pytest.fixture(scope="module")
def truth():
    return simulated()


def _same_points(got, want, *, atol, snr_atol):
    assert got.frame.tolist() == want.frame.tolist()
    np.testing.assert_allclose(got.range_m, want.range_m, atol=atol)
    np.testing.assert_allclose(got.omega_rad, want.omega_rad, atol=atol)
    np.testing.assert_allclose(got.doppler_mps, want.doppler_mps, atol=atol)
    np.testing.assert_allclose(got.snr_db, want.snr_db, atol=snr_atol)


def test_import_uart_sample(tmp_path, truth, capsys):
    out = tmp_path / "uart.h5"
    rc = main(["import", "ti-uart", "--node", f"S1={TI_DATA / 'oob_uart_S1.bin'}", "--cfg",
               str(TI_DATA / "iwr1843_oob.cfg"), "--mount", "S1=0.8,5", "-o", str(out)])
    assert rc == 0, capsys.readouterr().err
    rec = read_recording(out)
    assert rec.frame_period_s == pytest.approx(0.05)            # from the .cfg
    # float32 positions on the wire, SNR in 0.1 dB steps.
    _same_points(rec.nodes["S1"].point_cloud, truth.nodes["S1"].point_cloud, atol=2e-5,
                 snr_atol=0.051)


@pytest.mark.parametrize("frame", ["sensor", "room"])
def test_import_table_samples(tmp_path, truth, frame, capsys):
    out = tmp_path / "table.h5"
    args = ["import", "table", "--table", str(TI_DATA / f"points_{frame}_frame.csv"),
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
    args = ["import", "table", "--node", f"S1={TI_DATA / 'points_sensor_frame.csv'}",
            "--frame-period", "0.05", "--mount", "S1=0.8,5", "--height-band", "0.5,1.5",
            "-o", str(out)]
    # The table holds two nodes: --node with a multi-node table is a usage error
    # that names the option to use.
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "holds 2 nodes" in err and "import it with --table" in err
    import pandas as pd
    df = pd.read_csv(TI_DATA / "points_sensor_frame.csv")
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
    assert main(["import", "ti-uart", "--node", f"S1={TI_DATA / 'oob_uart_S1.bin'}", "-o",
                 out]) == 2
    assert "frame period is unknown" in capsys.readouterr().err
    assert main(["import", "table", "--table", str(TI_DATA / "points_sensor_frame.csv"),
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
    assert main(["import", "dca1000", "--cfg", str(TI_DATA / "dca1000_small.cfg"), "--board",
                 "AWR1843BOOST", "--sub-frame", str(sub_frame), "--node",
                 f"S1={TI_DATA / 'dca1000_small.bin'}", "-o", str(out)]) == 0
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


# ``mmsnap import`` -> ``process`` -> ``calibrate`` -> ``fuse`` on TI formats made from one
# simulated 2D scene recovers the node poses and the target's states within 1.2x the error
# of the same scene processed directly in 2D. The scene's point clouds are lifted into
# raised, tilted 3D sensors (tests/ti_samples.py) and written as a sensor-frame CSV, a
# room-frame CSV and out-of-box UART logs.
#
# Measured (200 frames at 20 fps, configuration C, seed 2; S2's pose error, fused position /
# velocity RMSE against the truth): direct 2D 7.66 mm, 0.053 deg, 16.8 mm, 0.397 m/s; both
# CSV imports the same to 1e-8 m, the UART logs (float32 on the wire) to 5e-6 m and 2e-4 m/s.


N_FRAMES = 200


SEED = 2


MOUNT_ARGS = [a for name, (h, t) in MOUNTS.items()
              for a in ("--mount", f"{name}={h},{np.rad2deg(t):g}")]


@pytest.fixture(scope="module")
def scene():
    return simulated(n_frames=N_FRAMES, seed=SEED)


def _import(kind: str, sim, d) -> list[str]:
    """The ``mmsnap import`` arguments of one format of the scene."""
    out = ["-o", str(d / f"{kind}.h5")]
    if kind == "uart":
        args = ["import", "ti-uart", "--frame-period", str(FRAME_PERIOD_S), *MOUNT_ARGS]
        for k, (name, (h, t)) in enumerate(MOUNTS.items()):
            write_uart_log(d / f"{name}.bin", sim.nodes[name].point_cloud, h, t, seed=k,
                           first_frame=0)
            args += ["--node", f"{name}={d / f'{name}.bin'}"]
        return args + out
    room = kind == "room_csv"
    table_rows(sim, room=room).to_csv(d / f"{kind}.csv", index=False, float_format="%.6f")
    args = ["import", "table", "--table", str(d / f"{kind}.csv"), "--frame-period",
            str(FRAME_PERIOD_S), *MOUNT_ARGS]
    if room:
        for name, pose in sim.truth.node_poses.items():
            x, y, phi = pose
            args += ["--room-pose", f"{name}={x:g},{y:g},{np.rad2deg(phi):g}"]
    return args + out


def _errors(path, sim) -> dict[str, float]:
    assert main(["process", str(path), "--no-progress"]) == 0
    assert main(["calibrate", str(path)]) == 0
    assert main(["fuse", str(path), "--no-progress"]) == 0
    rec = dataclasses.replace(read_recording(path), truth=sim.truth)
    m = evaluate_recording(rec, fused=read_fused(path))
    s2 = m["poses"]["S2"]
    return {"pose_m": s2["position_error_m"], "heading_rad": abs(s2["heading_error_rad"]),
            "position_rmse_m": m["fused"]["position_rmse_m"],
            "velocity_rmse_mps": m["fused"]["velocity_rmse_mps"],
            "n_success": m["fused"]["n_success"]}


@pytest.fixture(scope="module")
def direct(scene, tmp_path_factory):
    path = tmp_path_factory.mktemp("direct") / "direct.h5"
    write_recording(path, scene)
    return _errors(path, scene)


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["sensor_csv", "room_csv", "uart"])
def test_import_process_calibrate_fuse_recovers_poses_and_states(kind, scene, direct,
                                                                  tmp_path, capsys):
    assert main(_import(kind, scene, tmp_path)) == 0, capsys.readouterr().err
    got = _errors(tmp_path / f"{kind}.h5", scene)
    print(kind, got, "direct", direct)
    assert direct["pose_m"] < 0.02 and direct["position_rmse_m"] < 0.1
    assert got["n_success"] >= 0.95 * N_FRAMES
    for key in ("pose_m", "heading_rad", "position_rmse_m", "velocity_rmse_mps"):
        assert got[key] <= 1.2 * direct[key], (key, got[key], direct[key])


# ROS bags (tests/_rosbags.py writes them with rosbags' own writers).


def _real_bag_messages(recording_name):
    """The real point tables of ``recording_name`` as a TI driver's bag would
    hold them: one cloud per table frame at 20 fps (receive times from a
    Unix time), in ROS axes."""
    import csv

    t0_ns = 1_717_600_000 * 10**9
    out = {}
    for node in ("S1", "S2"):
        with open(REAL / f"{recording_name}_{node}.csv", newline="") as f:
            rows = np.array([[float(v) for v in r.values()] for r in csv.DictReader(f)])
        frames = rows[:, 0].astype(int)
        out[f"/ti_mmwave/radar_scan_pcl_{node[-1]}"] = [
            (t0_ns + int(fr) * 50_000_000, 0, rows[frames == fr, 2:5], rows[frames == fr, 5],
             rows[frames == fr, 6]) for fr in np.unique(frames)]
    return out


@pytest.mark.parametrize("ros, storage", [(1, "bag"), (2, "mcap")])
def test_real_tables_through_a_ros_bag_import_as_the_tables(tmp_path, capsys, ros, storage):
    """The real multiple-tracking recording written as a TI driver's bag
    (header.stamp 0, frame_id empty, ROS axes; its points in the room frame,
    as the recorder stored them) imports to the points of `import table`."""
    pytest.importorskip("rosbags")
    from _rosbags import write_bag

    room = ["--room-pose", "S1=0,0,0", "--room-pose", "S2=1.7,1.65,90"]
    bag = write_bag(tmp_path / ("mt.bag" if ros == 1 else "mt"),
                    _real_bag_messages("multiple_tracking"), ros=ros, storage=storage,
                    zero_stamps=True)
    assert main(["import", "rosbag", str(bag), "--topic", "/ti_mmwave/radar_scan_pcl_1=S1",
                 "--topic", "/ti_mmwave/radar_scan_pcl_2=S2", *REAL_MOUNTING, *room, "-o",
                 str(tmp_path / "bag.h5")]) == 0
    err = capsys.readouterr().err
    assert f"ROS {ros} ({storage}); time stamps: the bag's receive times" in err
    assert "clouds have header.stamp 0" in err and "frame_id ''" in err
    assert main(["import", "table", "--node", f"S1={REAL / 'multiple_tracking_S1.csv'}",
                 "--node", f"S2={REAL / 'multiple_tracking_S2.csv'}", *REAL_MOUNTING, *room,
                 "-o", str(tmp_path / "table.h5")]) == 0
    got, want = read_recording(tmp_path / "bag.h5"), read_recording(tmp_path / "table.h5")
    for name in ("S1", "S2"):
        a, b = got.nodes[name].point_cloud, want.nodes[name].point_cloud
        assert a.frame.tolist() == b.frame.tolist() and len(a) > 1000
        for k in ("range_m", "omega_rad", "doppler_mps", "snr_db"):  # float32 in the bag
            np.testing.assert_allclose(getattr(a, k), getattr(b, k), rtol=1e-6, atol=1e-6)
    assert got.metadata["source"] == f"rosbag{ros}-{storage}"
    assert got.metadata["rosbag_stamps"] == "receive"
    assert got.metadata["time_origin_s"] == pytest.approx(1_717_600_000, abs=1.0)


def test_a_rosbag_without_velocity_warns_and_without_a_period_names_the_bags(tmp_path, capsys,
                                                                             truth):
    pytest.importorskip("rosbags")
    from _rosbags import write_bag
    from ti_samples import lift

    msgs = {}
    for k, name in enumerate(("S1", "S2")):
        det = truth.nodes[name].point_cloud
        xyz, dop = lift(det, *MOUNTS[name], seed=k)
        msgs[f"/radar_{name}"] = [(10**18 + int(f) * 50_000_000, 10**9 + int(f) * 50_000_000,
                                   xyz[det.frame == f], dop[det.frame == f],
                                   det.snr_db[det.frame == f]) for f in np.unique(det.frame)]
    bag = write_bag(tmp_path / "lab", msgs, ros=2, velocity=False)
    base = ["import", "rosbag", str(bag), "--topic", "/radar_S1=S1", "--topic", "/radar_S2=S2",
            "-o", str(tmp_path / "o.h5")]
    assert main(base) == 2
    assert ("the frame period is unknown: give --frame-period or --cfg (the bag's clouds arrive "
            "/radar_S1 every 0.05 s, /radar_S2 every 0.05 s, median)") in capsys.readouterr().err
    assert main(base + ["--frame-period", "0.05", "--mount", "S1=0.8,5",
                        "--mount", "S2=1.2,15"]) == 0
    err = capsys.readouterr().err
    assert "time stamps: the clouds' header stamps" in err
    assert ("warning: /radar_S1 (S1) has no velocity field (the older radar-lab driver's "
            "layout): its Doppler is unknown and imported as 0 m/s") in err
    rec = read_recording(tmp_path / "o.h5")
    assert rec.metadata["rosbag_nodes_without_doppler"] == "S1,S2"
    got = rec.nodes["S1"].point_cloud
    want = truth.nodes["S1"].point_cloud
    np.testing.assert_allclose(got.range_m, want.range_m, atol=1e-5)   # float32 in the bag
    np.testing.assert_allclose(got.omega_rad, want.omega_rad, atol=1e-5)
    assert np.all(got.doppler_mps == 0.0)
    assert main(base + ["--frame-period", "0.05", "--topic", "/radar_S1=S3", "--overwrite"]) == 2
    assert "--topic /radar_S1 is given 2 times" in capsys.readouterr().err


def _stacked_table(src, dst, depth=10, period=0.05):
    """The recorder's saved frames of a data/real/darksz table: saved frame k
    holds the table frames k .. k + depth - 1 (oldest first), stamped k *
    period, as the TI user's path dumps them."""
    import csv
    with open(src, newline="") as f:
        rows = list(csv.reader(f))
    header, body = rows[0], rows[1:]
    k_frame, k_time = header.index("frame"), header.index("time_s")
    by_frame: dict[int, list] = {}
    for r in body:
        by_frame.setdefault(int(r[k_frame]), []).append(r)
    last = max(by_frame)
    out = [header]
    for k in range(last - depth + 2):
        for f in range(k, k + depth):
            for r in by_frame.get(f, []):
                r = list(r)
                r[k_frame], r[k_time] = str(k), f"{k * period:.2f}"
                out.append(r)
    with open(dst, "w", newline="") as f:
        csv.writer(f).writerows(out)


def test_destack_of_the_saved_stacks_gives_the_projects_tables(tmp_path):
    """The TI user's path (the recorder's 10-frame stacks as stored, room
    frame, static points in, `import table --destack`) gives the points of
    data/real/darksz's own conversion, frame for frame. Dropping every point
    equal to one of the previous stack lost 756 of S2's 4,828 points (the
    static reflectors' repeats): 89.5% of the fused rows inside the room
    against 96.5%."""
    real = DATA / "real" / "darksz"
    args = ["--frame-period", "0.05", "--mount", "S1=0.8,0", "--mount", "S2=1.1,0",
            "--room-pose", "S1=0,0,0", "--room-pose", "S2=1.7,1.65,90",
            "--height-band", "0.2,2.0"]
    recs = {}
    for name, destack in (("own", False), ("stacked", True)):
        nodes = []
        for node in ("S1", "S2"):
            src = real / f"multiple_tracking_{node}.csv"
            if destack:
                _stacked_table(src, tmp_path / f"{node}.csv")
                src = tmp_path / f"{node}.csv"
            nodes += ["--node", f"{node}={src}"]
        out = tmp_path / f"{name}.h5"
        assert main(["import", "table", *nodes, *args, "-o", str(out)]
                    + (["--destack"] if destack else [])) == 0
        recs[name] = read_recording(out)
    for node in ("S1", "S2"):
        own, got = (recs[k].nodes[node].point_cloud for k in ("own", "stacked"))
        assert len(got.frame) == len(own.frame)
        for field in ("frame", "range_m", "omega_rad", "doppler_mps", "snr_db"):
            np.testing.assert_array_equal(getattr(got, field), getattr(own, field), err_msg=field)


def test_a_numeric_node_column_takes_mount_options_by_its_names(tmp_path, capsys):
    """Before: a node column of 1 and 2 named the nodes '1.0' and '2.0', and
    `--mount 1=...` was refused as naming no node (issue 29)."""
    table = tmp_path / "numeric.csv"
    table.write_text("node,frame,x,y,z,doppler\n" + "".join(
        f"{n},{k},{0.5 * n},{2 + 0.05 * k},0.0,0.1\n" for n in (1, 2) for k in range(20)))
    out = tmp_path / "numeric.h5"
    assert main(["import", "table", "--table", str(table), "--frame-period", "0.1", "--mount",
                 "1=0.8,5", "--mount", "2=1.2,0", "-o", str(out)]) == 0, capsys.readouterr().err
    rec = read_recording(out)
    assert rec.node_names == ["1", "2"]
    assert (rec.metadata["1_height_m"], rec.metadata["2_height_m"]) == (0.8, 1.2)
    assert rec.metadata["2_tilt_rad"] == 0.0
