"""Bad TI inputs get errors naming the line (CSV) or the frame (UART), and
the CLI reports them in one line naming the file (issue 14, "Test data":
bad input gets a clear error naming the line or frame). Before, a CSV with
one non-numeric or empty value said only "column frame must be numeric" or
"x_m must be finite; point K" (K counted within one node's points, not a
line of the file), and the missing-column error named only the library's
column names (z_m, doppler_mps), not the log's (z, doppler)."""

from __future__ import annotations

import pytest

from mmsnap_graph.app.cli import main
from mmsnap_graph.errors import FileFormatError
from mmsnap_graph.io.point_table import read_point_tables

from _shared import TI_DATA

LINES = (TI_DATA / "points_sensor_frame.csv").read_text().splitlines()


def _csv(tmp_path, lines, name="log.csv"):
    path = tmp_path / name
    path.write_text("\n".join(lines) + "\n")
    return path


def _replace(line: str, column: int, value: str) -> str:
    cells = line.split(",")
    cells[column] = value
    return ",".join(cells)


def test_a_non_numeric_value_names_its_line(tmp_path):
    lines = list(LINES[:30])
    lines[11] = _replace(lines[11], 1, "x!")                  # frame of line 12
    with pytest.raises(FileFormatError, match=r"log.csv: column frame must be numeric; "
                                              r"line 12 holds 'x!'"):
        read_point_tables(_csv(tmp_path, lines))


def test_an_empty_value_of_another_node_names_its_line_past_comments(tmp_path):
    header, rows = LINES[0], LINES[1:]
    s2 = [r for r in rows if r.startswith("S2,")][:5]
    s1 = [r for r in rows if r.startswith("S1,")][:5]
    s2[3] = _replace(s2[3], 3, "")                           # x of the 4th S2 point
    lines = ["# logged by a script", header, *s1, "", *s2]
    # line 1 comment, 2 header, 3-7 S1, 8 blank, 9-13 S2: the 4th S2 row is line 12
    with pytest.raises(FileFormatError, match=r"column x_m must be finite; point 3 "
                                              r"\(line 12\) holds nan"):
        read_point_tables(_csv(tmp_path, lines))


def test_a_dataframe_names_the_row(tmp_path):
    import pandas as pd
    df = pd.read_csv(TI_DATA / "points_sensor_frame.csv").head(20)
    df["frame"] = df["frame"].astype(float)
    df.loc[7, "frame"] = 2.5
    with pytest.raises(FileFormatError, match=r"frame must hold integers; row 7 holds 2.5"):
        read_point_tables(df)


def test_missing_columns_also_name_the_logs_usual_names(tmp_path):
    lines = [",".join(c for c in line.split(",")[:6]) for line in LINES[:5]]  # no doppler
    with pytest.raises(FileFormatError, match=r"need \['doppler_mps'\] \(or doppler\)"):
        read_point_tables(_csv(tmp_path, lines))


def test_the_cli_reports_the_line_in_one_line(tmp_path, capsys):
    lines = list(LINES[:30])
    lines[20] = _replace(lines[20], 6, "fast")               # doppler of line 21
    path = _csv(tmp_path, lines, "bad.csv")
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
