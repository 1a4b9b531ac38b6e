"""Point tables (mmsnap_graph.io.point_table): CSV without pandas, malformed
columns as typed errors, frame numbers and time stamps that fit."""

from __future__ import annotations

import os
import re
import subprocess
import sys

import numpy as np
import pytest

from mmsnap_graph.errors import FileFormatError, ValidationError
from mmsnap_graph.io.point_table import read_point_table, read_point_tables

from _shared import ROOT, TI_DATA

HEADER = "node,frame,time_s,x,y,z,doppler,snr"
SENSOR_LINES = (TI_DATA / "points_sensor_frame.csv").read_text().splitlines()


def _csv(tmp_path, rows, header=HEADER, name="log.csv"):
    path = tmp_path / name
    path.write_text("\n".join([header, *rows]) + "\n")
    return path


def _rows(n=4, node="S1"):
    return [f"{node},{k},{100 + 0.05 * k:.2f},0.5,2.0,0.1,0.3,20" for k in range(n)]


def test_csv_is_read_without_pandas(tmp_path):
    """Importing pandas fails in the child (as after a plain ``pip install .``);
    the sample CSV is still read, through the library and the CLI."""
    code = (
        "import sys; sys.modules['pandas'] = None\n"
        "from mmsnap_graph.io.point_table import read_point_tables\n"
        f"clouds = read_point_tables({str(TI_DATA / 'points_sensor_frame.csv')!r})\n"
        "print(sorted(clouds), sum(len(c) for c in clouds.values()))\n"
        "from mmsnap_graph.app.cli import main\n"
        f"raise SystemExit(main(['import', 'table', '--table', "
        f"{str(TI_DATA / 'points_sensor_frame.csv')!r}, '--frame-period', '0.05', "
        f"'-o', {str(tmp_path / 'o.h5')!r}]))\n")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get(
        "PYTHONPATH", "")]))
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          env=env, cwd=tmp_path, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("['S1', 'S2']")
    assert "wrote" in done.stdout


def test_csv_matches_the_pandas_reading():
    pd = pytest.importorskip("pandas")
    path = TI_DATA / "points_sensor_frame.csv"
    mine = read_point_tables(path)
    theirs = read_point_tables(pd.read_csv(path))
    assert list(mine) == list(theirs)
    for name in mine:
        np.testing.assert_array_equal(mine[name].frame, theirs[name].frame)
        np.testing.assert_array_equal(mine[name].points_xyz, theirs[name].points_xyz)
        np.testing.assert_array_equal(mine[name].snr_db, theirs[name].snr_db)
        np.testing.assert_array_equal(mine[name].time_s, theirs[name].time_s)


def test_csv_comments_blank_lines_quotes_and_spaces(tmp_path):
    path = tmp_path / "log.csv"
    path.write_text("# logged by hand\n\nnode, frame, x, y, z, doppler\n"
                    '"S1", 0, 1, 2, 0, 0.5\n# a comment\n S1 , 1, 1, 2, 0, 0.5\n')
    cloud = read_point_table(path)
    assert cloud.frame.tolist() == [0, 1]


def test_a_short_csv_line_is_named(tmp_path):
    rows = _rows()
    rows[2] = rows[2].rsplit(",", 1)[0]
    with pytest.raises(FileFormatError, match=r"line 4 has 7 cells, the header \(line 1\) "
                                              "names 8 columns"):
        read_point_tables(_csv(tmp_path, rows))


@pytest.mark.parametrize("header", [HEADER + ",x", HEADER.replace("snr", "X")])
def test_duplicate_column_names(tmp_path, header):
    rows = [r + (",1" if header.endswith(",x") else "") for r in _rows()]
    with pytest.raises(FileFormatError, match=r"columns 'x' and '(x|X)' have the same name"):
        read_point_tables(_csv(tmp_path, rows, header=header))


def test_duplicate_dataframe_columns():
    pd = pytest.importorskip("pandas")
    df = pd.DataFrame(np.ones((3, 6)), columns=["frame", "x", "y", "z", "doppler", "x"])
    with pytest.raises(FileFormatError, match="same name"):
        read_point_tables(df)


def test_two_aliases_of_one_column(tmp_path):
    rows = [r + ",0.4" for r in _rows()]
    with pytest.raises(FileFormatError, match=r"columns \['doppler', 'velocity'\] all mean "
                                              r"doppler_mps.*--columns"):
        read_point_tables(_csv(tmp_path, rows, header=HEADER + ",velocity"))


def _npz(tmp_path, **columns):
    path = tmp_path / "points.npz"
    np.savez(path, **columns)
    return path


def _columns(n=4):
    return dict(frame=np.arange(n), x=np.ones(n), y=np.full(n, 2.0), z=np.zeros(n),
                doppler=np.zeros(n))


def test_npz_ragged_columns(tmp_path):
    cols = _columns()
    cols["x"] = np.ones(3)
    with pytest.raises(FileFormatError, match=r"columns differ in length"):
        read_point_tables(_npz(tmp_path, **cols))


def test_npz_zero_d_and_two_d_columns(tmp_path):
    cols = _columns()
    cols["x"] = np.float64(1.0)
    with pytest.raises(FileFormatError, match=r"column x must be one-dimensional.*shape \(\)"):
        read_point_tables(_npz(tmp_path, **cols))
    cols["x"] = np.ones((4, 2))
    with pytest.raises(FileFormatError, match=r"column x must be one-dimensional"):
        read_point_tables(_npz(tmp_path, **cols))


def test_npz_object_column(tmp_path):
    cols = _columns()
    cols["x"] = np.array([1.0, None, 2.0, 3.0], dtype=object)
    with pytest.raises(FileFormatError, match=r"not a plain NumPy array file"):
        read_point_tables(_npz(tmp_path, **cols))


def test_complex_and_mapping_columns():
    cols = _columns()
    cols["x"] = cols["x"] * 1j
    with pytest.raises(FileFormatError, match=r"column x has dtype complex128"):
        read_point_tables(cols)


@pytest.mark.parametrize("value", ["1e30", "18446744073709551615", "-1e300"])
def test_frame_numbers_beyond_int64_are_errors(tmp_path, value):
    rows = _rows()
    rows[1] = rows[1].replace("S1,1,", f"S1,{value},")
    with pytest.raises(FileFormatError, match=re.escape(
            f"column frame must hold integers; line 3 holds {float(value)!r}")):
        read_point_tables(_csv(tmp_path, rows))


def test_time_stamp_beyond_any_clock(tmp_path):
    rows = _rows()
    rows[2] = rows[2].replace(",100.10,", ",1e308,")
    with pytest.raises(FileFormatError, match=r"column time_s holds 1e\+308 s at line 4"):
        read_point_tables(_csv(tmp_path, rows))


def test_tiny_frame_period_overflows_no_frame_number(tmp_path):
    rows = [r.split(",", 2)[0] + "," + r.split(",", 2)[2] for r in _rows()]
    path = _csv(tmp_path, rows, header=HEADER.replace("frame,", ""))
    with pytest.raises(FileFormatError, match=r"time stamps span 0.15 s, 1.5e\+299 frames"):
        read_point_tables(path, frame_period_s=1e-300)
    for bad in (0.0, -1.0, float("nan"), "0.05"):
        with pytest.raises(ValidationError, match="frame_period_s"):
            read_point_tables(path, frame_period_s=bad)


@pytest.mark.parametrize("cell", ["", "  "])
def test_empty_node_cell_names_its_line(tmp_path, cell):
    rows = _rows() + _rows(node="S2")
    rows[5] = cell + rows[5][2:]
    with pytest.raises(FileFormatError, match=r"column node is empty at line 7"):
        read_point_tables(_csv(tmp_path, rows))


def test_columns_mapping_for_gui_headers(tmp_path):
    path = _csv(tmp_path, [f"{k},{0.5 + k},2.0,0.1,0.3" for k in range(3)],
                header="Frame #,X [m],Y [m],Z [m],Velocity [m/s]")
    mapping = {"Frame #": "frame", "X [m]": "x", "y [M]": "y", "Z [m]": "z",
               "Velocity [m/s]": "doppler"}
    cloud = read_point_table(path, columns=mapping)
    assert cloud.x_m.tolist() == [0.5, 1.5, 2.5]
    assert cloud.doppler_mps.tolist() == [0.3] * 3
    with pytest.raises(FileFormatError, match=r"renames 'W \[m\]', which the table does not "
                                              "have"):
        read_point_table(path, columns={**mapping, "W [m]": "x"})
    with pytest.raises(FileFormatError, match=r"renames 'X \[m\]' to 'xx', which is not a "
                                              "column name"):
        read_point_table(path, columns={**mapping, "X [m]": "xx"})


def test_one_radar_reader_names_the_cli_option(tmp_path):
    path = _csv(tmp_path, _rows() + _rows(node="S2"))
    with pytest.raises(FileFormatError, match=r"mmsnap import table --table"):
        read_point_table(path)


def test_seeded_mutations_of_the_sample_raise_only_project_errors(tmp_path):
    """300 seeded edits of the sample CSV (odd numbers, empty and text cells,
    missing cells, duplicated headers), each read and turned into a recording:
    a project error or a recording, never another exception."""
    from mmsnap_graph.errors import MmsnapError
    from mmsnap_graph.io.point_cloud import recording_from_point_clouds
    lines = SENSOR_LINES[:120]
    odd = ["", "nan", "inf", "-inf", "1e308", "-1e308", "18446744073709551615", "x", "1e-300",
           "2.5", " ", "0x10", "1e30"]
    rng = np.random.default_rng(7)
    outcomes = {"error": 0, "read": 0}
    for case in range(300):
        rows = [line.split(",") for line in lines]
        for _ in range(int(rng.integers(1, 4))):
            r = int(rng.integers(0, len(rows)))
            c = int(rng.integers(0, len(rows[r])))
            kind = rng.integers(0, 10)
            if kind == 0:
                del rows[r][c]                          # a missing cell
            elif kind == 1 and r == 0:
                rows[0][c] = rows[0][(c + 1) % len(rows[0])]   # a duplicated header
            else:
                rows[r][c] = str(rng.choice(odd))
        path = tmp_path / f"m{case}.csv"
        path.write_text("\n".join(",".join(r) for r in rows) + "\n")
        try:
            clouds = read_point_tables(path, frame_period_s=0.05)
            recording_from_point_clouds(clouds, frame_period_s=0.05)
            outcomes["read"] += 1
        except MmsnapError:
            outcomes["error"] += 1
    assert outcomes["error"] > 100 and outcomes["read"] > 10, outcomes


@pytest.mark.parametrize("column, value", [("x", "1e308"), ("z", "-2e4"), ("doppler", "5000")])
def test_points_beyond_any_radar_are_errors(tmp_path, column, value):
    rows = _rows()
    cells = rows[1].split(",")
    cells[HEADER.split(",").index(column)] = value
    rows[1] = ",".join(cells)
    with pytest.raises(FileFormatError, match=rf"column {column}_m\w* must lie within "
                                              rf"\+-10+; point 1 \(line 3\) holds "
                                              + re.escape(repr(float(value)))):
        read_point_tables(_csv(tmp_path, rows))
