"""``mmsnap import``: unit mistakes, frame clocks that disagree, and messages
that name the command-line options."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, strategies as st

from mmsnap_graph.app.cli import main
from mmsnap_graph.io import read_recording

from _shared import TI_DATA, DATA
from _fuzz import CLI_FUZZ, one_line_data_error

SENSOR_CSV = TI_DATA / "points_sensor_frame.csv"


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
    assert main(args) == 1
    assert "missing columns" in capsys.readouterr().err
    assert main(args + ["--columns", "X [m]=x", "--columns", "Y [m]=y", "--columns", "Z [m]=z",
                        "--columns", "Velocity [m/s]=doppler"]) == 0
    assert len(read_recording(tmp_path / "gui.h5").nodes["S1"].point_cloud) == 60


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


UART = (DATA / "ti" / "oob_uart_S1.bin").read_bytes()


CSV_LINES = (DATA / "ti" / "points_sensor_frame.csv").read_text().splitlines()


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


def _csv_lines(tmp_path, lines, name="log.csv"):
    path = tmp_path / name
    path.write_text("\n".join(lines) + "\n")
    return path


def _replace_cell(line: str, column: int, value: str) -> str:
    cells = line.split(",")
    cells[column] = value
    return ",".join(cells)


def test_the_cli_reports_the_line_in_one_line(tmp_path, capsys):
    lines = list(SENSOR_LINES[:30])
    lines[20] = _replace_cell(lines[20], 6, "fast")               # doppler of line 21
    path = _csv_lines(tmp_path, lines, "bad.csv")
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
