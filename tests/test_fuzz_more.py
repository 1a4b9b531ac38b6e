"""Property-based fuzzing of the public entry points the other fuzz files do
not cover (issue 13, "A fuzz suite"): the per-node EKF, the OS-CFAR
functions, ``mmsnap demo`` on bad sample files and ``mmsnap import`` on bad
inputs. Properties: only the project's errors (:class:`MmsnapError`) are
raised; a result that says it succeeded holds finite numbers and a
positive-definite covariance; a CLI run on a bad input exits 1 with one
line naming the file (never a traceback, never exit 2)."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mmsnap_graph.app.cli import main
from mmsnap_graph.errors import MmsnapError
from mmsnap_graph.radar.cfar import CfarConfig, os_cfar_2d, os_cfar_alpha, os_cfar_cells
from mmsnap_graph.tracking.ekf import EkfConfig, LocalTracker, track_centroids
from mmsnap_graph.data.recording import Detections

DATA = Path(__file__).resolve().parents[1] / "data"
FUZZ = settings(max_examples=40, deadline=None, derandomize=True, database=None,
                report_multiple_bugs=False,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much,
                                       HealthCheck.function_scoped_fixture])
CLI_FUZZ = settings(FUZZ, max_examples=12)

#: Floats a fuzzer should try: ordinary, edge and non-finite values.
EDGE = st.one_of(st.floats(-50, 50, allow_nan=False), st.sampled_from(
    [0.0, -0.0, 1e-300, -1e-300, 1e300, -1e300, np.pi, -np.pi, 4.0, np.nan, np.inf, -np.inf]))
ANY_VALUE = st.one_of(EDGE, st.integers(-10, 10), st.booleans(), st.none(), st.text(max_size=3),
                      st.lists(st.integers(0, 3), max_size=2))


def assert_tracks_sound(out) -> None:
    for track_id, x, p in out:
        assert isinstance(int(track_id), int)
        assert np.all(np.isfinite(x)) and np.all(np.isfinite(p)), (x, p)
        np.testing.assert_allclose(p, p.T, rtol=1e-9, atol=1e-12)
        assert np.linalg.eigvalsh(p).min() > 0, p


# ------------------------------------------------------------------ EKF
rows = st.lists(st.tuples(EDGE, EDGE, EDGE), min_size=0, max_size=4)


@settings(FUZZ, max_examples=25)
@given(frames=st.lists(rows, min_size=1, max_size=12),
       period=st.one_of(st.none(), st.floats(1e-3, 1.0), EDGE))
def test_local_tracker_steps_raise_only_typed_errors(frames, period):
    tracker = LocalTracker()
    for z in frames:
        z = np.array(z, dtype=float).reshape(-1, 3)
        try:
            out = tracker.step(z, frame_period_s=period)
        except MmsnapError:
            continue
        assert_tracks_sound(out)


@settings(FUZZ, max_examples=15)
@given(start=st.lists(st.tuples(st.floats(0.5, 10), st.floats(-2.5, 2.5), st.floats(-3, 3)),
                      min_size=1, max_size=3),
       jitter=st.floats(0.0, 0.5), bad=st.tuples(EDGE, EDGE, EDGE))
def test_local_tracker_on_confirmed_tracks_and_one_odd_row_is_sound(start, jitter, bad):
    tracker = LocalTracker()
    rng = np.random.default_rng(0)
    base = np.array(start)
    for k in range(8):
        z = base + jitter * rng.normal(size=base.shape) * [0.05, 0.05, 0.1]
        z[:, 1] = np.clip(z[:, 1], -np.pi, np.pi)
        z[:, 0] = np.abs(z[:, 0])
        if k == 5:
            z = np.vstack([z, bad])
        try:
            out = tracker.step(z)
        except MmsnapError:
            continue
        assert_tracks_sound(out)


@settings(FUZZ, max_examples=25)
@given(kwargs=st.dictionaries(st.sampled_from(["frame_period_s", "sigma_a_mps2", "gate_probability",
                                               "confirm_hits", "confirm_window_s", "max_coast_s",
                                               "max_misses", "confirm_window",
                                               "doppler_wrap_mps", "measurement_std"]),
                              ANY_VALUE, min_size=1, max_size=2))
def test_ekf_config_raises_only_typed_errors(kwargs):
    try:
        cfg = EkfConfig(**kwargs)
    except MmsnapError:
        return
    det = Detections(frame=np.arange(6), range_m=np.linspace(3, 3.3, 6),
                     omega_rad=np.full(6, 0.2), doppler_mps=np.full(6, 0.4))
    try:
        tracks = track_centroids(det, cfg)
    except MmsnapError:
        return
    assert np.all(np.isfinite(tracks.state))


# ------------------------------------------------------------------ CFAR
def power_maps():
    shape = st.tuples(st.integers(1, 12), st.integers(1, 9))
    return shape.flatmap(lambda s: st.lists(st.one_of(st.floats(0, 1e3), EDGE),
                                            min_size=s[0] * s[1], max_size=s[0] * s[1])
                         .map(lambda v: np.array(v, dtype=float).reshape(s)))


cfar_configs = st.builds(
    dict, guard_cells=st.tuples(st.integers(0, 3), st.integers(0, 2)),
    train_cells=st.tuples(st.integers(0, 4), st.integers(0, 3)),
    rank_fraction=st.one_of(st.floats(0.05, 1.0), EDGE), pfa=st.one_of(
        st.floats(1e-12, 0.5), st.sampled_from([1e-300, 1e-100, 0.999999]), EDGE))


@FUZZ
@given(power=power_maps(), cfg=cfar_configs, channels=st.one_of(st.integers(1, 4), ANY_VALUE))
def test_os_cfar_raises_only_typed_errors_and_agrees_cell_by_cell(power, cfg, channels):
    try:
        config = CfarConfig(**cfg)
        detected, z = os_cfar_2d(power, config, channels)
    except MmsnapError:
        return
    assert detected.shape == power.shape and detected.dtype == bool
    assert np.all(np.isfinite(z))
    r, c = np.nonzero(np.ones(power.shape, bool))
    cells, z_cells = os_cfar_cells(power, r, c, config, channels)
    np.testing.assert_array_equal(cells, detected.ravel())
    np.testing.assert_allclose(z_cells, z.ravel())


@FUZZ
@given(rows_=st.one_of(st.lists(st.integers(-3, 14), max_size=4), ANY_VALUE),
       cols_=st.one_of(st.lists(st.integers(-3, 10), max_size=4), ANY_VALUE))
def test_os_cfar_cells_rejects_bad_cells_with_typed_errors(rows_, cols_):
    power = np.random.default_rng(1).exponential(size=(12, 8))
    try:
        detected, z = os_cfar_cells(power, rows_, cols_, CfarConfig())
    except MmsnapError:
        return
    assert detected.shape == z.shape and np.all(np.isfinite(z))


@FUZZ
@given(n_train=ANY_VALUE, rank=ANY_VALUE, pfa=st.one_of(EDGE, st.sampled_from([1e-300, 1e-200])),
       channels=ANY_VALUE)
def test_os_cfar_alpha_raises_only_typed_errors(n_train, rank, pfa, channels):
    """Found: unhashable arguments gave TypeError (the cache), a pfa near 1
    brentq's ValueError, a pfa of 1e-300 the bracket's end as the factor."""
    try:
        alpha = os_cfar_alpha(n_train, rank, pfa, channels)
    except MmsnapError:
        return
    assert np.isfinite(alpha) and alpha > 0


@pytest.mark.parametrize("args", [([16], 12, 1e-6, 1), (16, 12, 0.999999, 1), (16, 12, 1e-300, 1),
                                  (16, 12, 1e-6, [2])])
def test_os_cfar_alpha_found_cases_are_configuration_errors(args):
    from mmsnap_graph.errors import ConfigurationError

    with pytest.raises(ConfigurationError):
        os_cfar_alpha(*args)


# ------------------------------------------------------------------ demo
@pytest.fixture(scope="module")
def sample(tmp_path_factory):
    d = tmp_path_factory.mktemp("fuzz_more")
    path = d / "config_B_straight.h5"
    shutil.copy(DATA / "config_B_straight.h5", path)
    return path.read_bytes()


def one_line_data_error(code, err, name):
    assert code == 1, err
    assert len(err) == 1 and ": error: " in err[0] and name in err[0], err


@CLI_FUZZ
@given(cut=st.floats(0.0, 0.95), flips=st.lists(st.tuples(st.integers(0, 4095),
                                                           st.integers(0, 7)), max_size=3))
def test_demo_on_a_damaged_sample_exits_1_naming_it(sample, tmp_path_factory, capsys, cut, flips):
    d = tmp_path_factory.mktemp("demo_data")
    data = bytearray(sample[: max(int(len(sample) * cut), 0)]) if cut > 0.01 else bytearray(sample)
    for at, bit in flips:
        if at < len(data):
            data[at] ^= 1 << bit
    if cut <= 0.01 and not flips:
        data = bytearray(b"not a recording")
    (d / "config_B_straight.h5").write_bytes(bytes(data))
    code = main(["demo", "--data", str(d), "-c", "B", "-n", "20", "--cube-frames", "0",
                 "--no-figures", "--no-progress", "--out", str(d / "out")])
    err = capsys.readouterr().err.strip().splitlines()
    if code == 0:  # a flip that hit nothing the demo reads
        return
    one_line_data_error(code, err, "config_B_straight.h5")


# ------------------------------------------------------------------ import
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
