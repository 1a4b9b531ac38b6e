"""Tabular point-cloud import (mmsnap_graph.io.point_table)."""

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings, strategies as st

from factors.projection import spherical_to_cartesian
from mmsnap_graph.errors import FileFormatError, MmsnapError, ValidationError
from mmsnap_graph.io.point_table import read_point_table, read_point_tables


def _table(seed=0, n=40):
    rng = np.random.default_rng(seed)
    frame = np.sort(rng.integers(0, 10, n))
    return pd.DataFrame({"frame": frame, "x": rng.uniform(-3, 3, n), "y": rng.uniform(1, 6, n),
                         "z": rng.uniform(-1, 1, n), "doppler": rng.uniform(-1, 1, n),
                         "snr": rng.uniform(5, 25, n), "time_s": 1000 + frame * 0.05})


@pytest.mark.parametrize("kind", ["frame", "csv", "npy", "npz"])
def test_cartesian_round_trip(kind, tmp_path):
    df = _table()
    if kind == "frame":
        src = df
    elif kind == "csv":
        src = tmp_path / "points.csv"
        df.to_csv(src, index=False)
    elif kind == "npy":
        src = tmp_path / "points.npy"
        np.save(src, df.to_records(index=False))
    else:
        src = tmp_path / "points.npz"
        np.savez(src, **{c: df[c].to_numpy() for c in df.columns})
    cloud = read_point_table(src)
    np.testing.assert_array_equal(cloud.frame, df["frame"])
    np.testing.assert_allclose(cloud.points_xyz, df[["x", "y", "z"]].to_numpy(), rtol=1e-15)
    np.testing.assert_allclose(cloud.doppler_mps, df["doppler"], rtol=1e-15)
    np.testing.assert_allclose(cloud.snr_db, df["snr"], rtol=1e-15)
    np.testing.assert_allclose(cloud.time_s, df["time_s"], rtol=1e-15)


def test_spherical_in_degrees_and_renamed_columns():
    rng = np.random.default_rng(1)
    r, az, el = rng.uniform(1, 5, 10), rng.uniform(-60, 60, 10), rng.uniform(-20, 20, 10)
    df = pd.DataFrame({"Timestamp": np.repeat([1.0e3, 1.05e3], 5), "Range": r, "Azimuth": az,
                       "Elevation": el, "Dop": rng.uniform(-1, 1, 10)})
    cloud = read_point_table(df, degrees=True, columns={"Dop": "doppler_mps"}, time_unit="ms",
                             frame_period_s=0.05)
    expected = spherical_to_cartesian(r, np.deg2rad(az), np.deg2rad(el))
    np.testing.assert_allclose(cloud.points_xyz, expected, atol=1e-12)
    assert cloud.frame.tolist() == [0] * 5 + [1] * 5
    assert cloud.snr_db is None


def test_frames_from_time_stamps_keep_gaps():
    df = pd.DataFrame({"time": [0.0, 0.05, 0.20, 0.20], "x": 0, "y": 1, "z": 0, "doppler": 0})
    assert read_point_table(df, frame_period_s=0.05).frame.tolist() == [0, 1, 4, 4]
    assert read_point_table(df).frame.tolist() == [0, 1, 2, 2]


def test_node_column_splits_the_table():
    df = _table()
    df["node"] = np.where(np.arange(len(df)) % 2, "S2", "S1")
    clouds = read_point_tables(df)
    assert list(clouds) == ["S1", "S2"]
    assert len(clouds["S1"]) + len(clouds["S2"]) == len(df)
    with pytest.raises(FileFormatError, match="holds 2 nodes"):
        read_point_table(df)


def test_missing_columns_name_them_and_the_file(tmp_path):
    path = tmp_path / "log.csv"
    _table().drop(columns=["z", "doppler"]).to_csv(path, index=False)
    with pytest.raises(FileFormatError, match=r"log.csv: missing columns: Cartesian points "
                                              r"need \['z_m', 'doppler_mps'\]"):
        read_point_table(path)
    with pytest.raises(FileFormatError, match=r"missing spherical columns"):
        read_point_table(_table(), coordinates="spherical")
    with pytest.raises(FileFormatError, match="a frame number .* or a time stamp"):
        read_point_table(_table().drop(columns=["frame", "time_s"]))


def test_other_errors(tmp_path):
    with pytest.raises(FileFormatError, match="does not exist"):
        read_point_table(tmp_path / "none.csv")
    with pytest.raises(FileFormatError, match="no column names"):
        read_point_table(np.zeros((3, 5)))
    with pytest.raises(ValidationError, match="coordinates="):
        read_point_table(_table(), coordinates="polar")
    df = _table()
    df.loc[3, "x"] = np.nan
    with pytest.raises(FileFormatError, match=r"x_m must be finite; point 3"):
        read_point_table(df)
    df = _table()
    df["frame"] = df["frame"] + 0.5
    with pytest.raises(FileFormatError, match="frame must hold integers"):
        read_point_table(df)


@settings(max_examples=100, deadline=None)
@given(st.lists(st.text(alphabet="0123456789.,-xyzabc\n", max_size=30), max_size=6))
def test_csv_reader_raises_only_project_errors(tmp_path_factory, lines):
    path = tmp_path_factory.mktemp("h") / "t.csv"
    path.write_text("frame,x,y,z,doppler\n" + "\n".join(lines))
    try:
        read_point_table(path)
    except MmsnapError:
        pass
