"""``mmsnap process --config FILE`` (TOML) and ``--show-config`` (issue 14, item 4)."""

import dataclasses
import re
import tomllib

import numpy as np
import pytest

from mmsnap_graph.app.cli import main
from mmsnap_graph.app.config_file import (
    ProcessConfig,
    process_config_from_mapping,
    process_config_to_toml,
    read_process_config,
    read_matching_config,
    matching_config_from_mapping,
    matching_config_to_toml,
)
from mmsnap_graph.errors import ConfigurationError, ValidationError
from mmsnap_graph.radar.cfar import CfarConfig
from mmsnap_graph.radar.chain import ChainConfig
from mmsnap_graph.radar.cluster import ClusterConfig
from mmsnap_graph.tracking.ekf import EkfConfig
from mmsnap_graph.sim import CLEAN
from mmsnap_graph.calibration import MatchingOptions

from _cli import run_cli
from _shared import ROOT


def _show(capsys, *argv) -> str:
    assert main(["process", "--show-config", *argv]) == 0
    return capsys.readouterr().out


def test_show_config_prints_every_default_and_reads_back_equal(tmp_path, capsys):
    text = _show(capsys)
    for table in ("[chain]", "[chain.cfar]", "[chain.cluster]", "[ekf]"):
        assert table in text
    # Every field of every configuration is printed (unset ones as comments).
    for cls in (ChainConfig, CfarConfig, ClusterConfig):
        for f in dataclasses.fields(cls):
            if f.name not in ("cfar", "cluster"):
                assert f"{f.name} = " in text, f.name
    assert "frame_period_s" not in text  # the recording gives it
    path = tmp_path / "defaults.toml"
    path.write_text(text)
    assert read_process_config(path) == ProcessConfig()


def test_a_file_changes_the_configuration_and_options_override_it(tmp_path, capsys):
    path = tmp_path / "sparse.toml"
    path.write_text("[chain]\nmin_range_m = 0.5\nmax_range_m = 12\n"
                    "[chain.cfar]\npfa = 1e-4\nguard_cells = [3, 2]\n"
                    "[chain.cluster]\npoint_targets = true\n"
                    "[ekf]\nconfirm_window_s = 0.3\nmax_coast_s = 0.4\nmeasurement_std = [0.1, 0.2, 0.3]\n")
    cfg = read_process_config(path)
    assert cfg.chain.min_range_m == 0.5 and cfg.chain.max_range_m == 12.0
    assert cfg.chain.cfar.pfa == 1e-4 and cfg.chain.cfar.guard_cells == (3, 2)
    assert cfg.chain.cluster.point_targets is True
    assert cfg.ekf.confirm_window_s == 0.3 and cfg.ekf.measurement_std == (0.1, 0.2, 0.3)
    # Round trip through --show-config with the file.
    again = tmp_path / "again.toml"
    again.write_text(_show(capsys, "--config", str(path)))
    assert read_process_config(again) == cfg
    # Explicit options win over the file.
    text = _show(capsys, "--config", str(path), "--pfa", "1e-3", "--sigma-a", "2.5")
    assert "pfa = 0.001" in text and "sigma_a_mps2 = 2.5" in text
    assert "guard_cells = [3, 2]" in text  # the rest of the file is kept


@pytest.mark.parametrize("doc, where", [
    ({"chain": {"min_rang_m": 1.0}}, "chain.min_rang_m"),
    ({"chain": {"cfar": {"pfa": 2.0}}}, "chain.cfar"),
    ({"chain": {"cfar": {"guard_cells": 3}}}, "chain.cfar.guard_cells"),
    ({"chain": {"clutter_removal": "yes"}}, "chain.clutter_removal"),
    ({"chain": {"cluster": 3}}, "chain.cluster"),
    ({"ekf": {"frame_period_s": 0.05}}, "ekf.frame_period_s"),
    ({"ekf": {"max_coast_s": -1.0}}, "ekf"),
    ({"tracker": {}}, "tracker"),
])
def test_bad_files_name_the_table_and_key(doc, where):
    with pytest.raises(ConfigurationError, match=where.replace(".", r"\.")):
        process_config_from_mapping(doc)


def test_a_syntax_error_names_the_file_and_line(tmp_path, capsys):
    path = tmp_path / "bad.toml"
    path.write_text("[chain]\nmin_range_m = \n")
    with pytest.raises(ConfigurationError, match=r"bad\.toml.*line 2"):
        read_process_config(path)
    assert main(["process", "--show-config", "--config", str(path)]) != 0
    assert "bad.toml" in capsys.readouterr().err
    with pytest.raises(ConfigurationError, match="cannot read"):
        read_process_config(tmp_path / "missing.toml")


def test_a_file_with_a_byte_order_mark_reads_as_without(tmp_path):
    """Before: a TOML file saved with a UTF-8 byte-order mark (Windows
    editors) was 'not valid TOML: Invalid statement (at line 1, column 1)'."""
    text = "[chain]\nmin_range_m = 0.5\n\n[matching]\nmax_lag_s = 0.2\n"
    plain, bom = tmp_path / "plain.toml", tmp_path / "bom.toml"
    plain.write_text(text, encoding="utf-8")
    bom.write_bytes(b"\xef\xbb\xbf" + text.encode("utf-8"))
    assert read_process_config(bom) == read_process_config(plain)
    assert read_process_config(bom).chain.min_range_m == 0.5
    assert read_matching_config(bom) == read_matching_config(plain)


def test_process_runs_with_the_file(tmp_path):
    """The file reaches the EKF: a confirmation count no track can meet
    leaves every node without tracks; the defaults give tracks."""
    io = pytest.importorskip("mmsnap_graph.io")
    from mmsnap_graph.sim import simulate_recording
    rec = simulate_recording("C", options=CLEAN, levels=("centroids",), n_frames=40, seed=3)
    path = tmp_path / "rec.h5"
    io.write_recording(path, rec)
    assert main(["process", str(path), "--centroids-only", "--no-progress"]) == 0
    assert all(len(n.tracks) > 0 for n in io.read_recording(path).nodes.values())
    cfg = tmp_path / "strict.toml"
    cfg.write_text("[ekf]\nconfirm_hits = 60\nconfirm_window_s = 9.0\n")
    assert main(["process", str(path), "--centroids-only", "--no-progress",
                 "--config", str(cfg)]) == 0
    got = io.read_recording(path)
    assert all(n.tracks is None or len(n.tracks) == 0 for n in got.nodes.values())
    # The centroids were not touched.
    np.testing.assert_array_equal(got.nodes["S1"].centroids.frame, rec.nodes["S1"].centroids.frame)


def test_to_toml_writes_infinities_and_strings_that_read_back():
    cfg = ProcessConfig(chain=ChainConfig(range_window="blackman"),
                        ekf=EkfConfig(sigma_a_mps2=0.5))
    assert process_config_from_mapping(__import__("tomllib").loads(
        process_config_to_toml(cfg))) == cfg


def test_the_ekf_noise_comes_from_the_data_unless_the_file_sets_it(tmp_path):
    """Default: each node's EKF takes the sigmas its own centroids identify
    (the simulator's 0.05 m, 0.08 rad, 0.1 m/s, not EkfConfig's 0.05, 0.1,
    0.2); a file with [ekf] measurement_std fixes them."""
    from mmsnap_graph.app.pipeline import ekf_noise_from_centroids
    from mmsnap_graph.sim import simulate_recording
    rec = simulate_recording("C", options=CLEAN, levels=("centroids",), n_frames=400, seed=5)
    ekf = ekf_noise_from_centroids(EkfConfig(), rec.nodes["S1"].centroids)
    np.testing.assert_allclose(ekf.measurement_std, (0.05, 0.08, 0.1), rtol=0.2)
    assert ProcessConfig().ekf_noise_from_data
    cfg = process_config_from_mapping({"ekf": {"measurement_std": [0.1, 0.2, 0.3]}})
    assert not cfg.ekf_noise_from_data and cfg.ekf.measurement_std == (0.1, 0.2, 0.3)
    # A file shown by --show-config reads back with the noise still from the data.
    assert read_process_config_text(process_config_to_toml(ProcessConfig()), tmp_path) \
        .ekf_noise_from_data


def read_process_config_text(text, tmp_path):
    path = tmp_path / "shown.toml"
    path.write_text(text)
    return read_process_config(path)


def test_process_and_calibrate_share_one_file(tmp_path, capsys):
    cfg = tmp_path / "both.toml"
    cfg.write_text("[chain]\nmin_range_m = 0.5\n[chain.cluster]\nsparse = true\n"
                   "[ekf]\nmax_coast_s = 0.4\n[matching]\nmin_common_s = 1.5\n")
    proc = read_process_config(cfg)
    assert proc.chain.min_range_m == 0.5 and proc.sparse is True and proc.ekf.max_coast_s == 0.4
    assert read_matching_config(cfg) == MatchingOptions(min_common_s=1.5)
    # Both --show-config outputs in one file read back to the same settings.
    _, text_p, _ = run_cli(capsys, "process", "--show-config", "--config", cfg)
    _, text_c, _ = run_cli(capsys, "calibrate", "--show-config", "--config", cfg)
    both = tmp_path / "again.toml"
    both.write_text(text_p + "\n" + text_c)
    assert read_process_config(both) == proc
    assert read_matching_config(both) == MatchingOptions(min_common_s=1.5)
    # A bad [matching] is calibrate's business: process ignores the table.
    cfg.write_text("[matching]\nmin_common_s = -1\n")
    assert read_process_config(cfg) == ProcessConfig()


# Hostile files: every value is either rejected with a ConfigurationError
# naming the key, or one that ``process`` runs with.


@pytest.mark.parametrize("data, key", [({"ekf": 5}, "ekf"), ({"chain": "x"}, "chain"),
                                       ({"scene": [1]}, "scene"), ({"matching": 2.0}, "matching"),
                                       ({"chain": {"cfar": 1}}, "chain.cfar")])
def test_a_value_where_a_table_belongs_is_a_configuration_error(data, key):
    with pytest.raises(ConfigurationError, match=f"{key} must be a table"):
        if key == "matching":
            matching_config_from_mapping(data)
        else:
            process_config_from_mapping(data)


@pytest.mark.parametrize("table, key, value", [
    ("ekf", "sigma_a_mps2", 1e308), ("ekf", "init_tangential_speed_std_mps", 1e308),
    ("ekf", "confirm_window_s", 1e308), ("ekf", "max_coast_s", 1e308),
    ("ekf", "max_misses", 2 ** 62), ("ekf", "confirm_window", 2 ** 62),
    ("ekf", "measurement_std", [1e308, 0.1, 0.1]), ("chain", "min_range_m", 1e308),
    ("chain", "angle_fft_size", 10 ** 8), ("chain.cfar", "guard_cells", [10 ** 6, 10 ** 6]),
    ("chain.cfar", "train_cells", [8, 10 ** 6]), ("chain", "dynamic_range_db", 1e308),
    ("scene", "window_s", 1e308), ("scene", "existence_window_s", 2 ** 62),
    ("scene", "cell_m", 1e-300), ("scene", "min_windows", 2 ** 62),
])
def test_values_beyond_the_physical_ranges_name_the_key(table, key, value):
    # Each of these was accepted and then overflowed or asked for terabytes
    # in ``process`` (or the radar-cube chain).
    parts = table.split(".")
    data = {parts[0]: {parts[1]: {key: value}} if len(parts) > 1 else {key: value}}
    with pytest.raises(ConfigurationError, match=key):
        process_config_from_mapping(data)


_ODD = [1e308, -1, float("nan"), 0, 2 ** 62, 1e-300, "x", 10 ** 9, -1e308, True,
        float("inf"), float("-inf")]  # non-finite bounds: issue 29


def _toml(value) -> str:
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return f'"{value}"'
    return "nan" if value != value else repr(value)


def _mutations():
    """(table, key, value) for every key of every table and every odd value."""
    cfg = ProcessConfig()
    tables = {"chain": cfg.chain, "chain.cfar": cfg.chain.cfar,
              "chain.cluster": cfg.chain.cluster, "ekf": cfg.ekf, "scene": cfg.scene}
    for table, obj in tables.items():
        for f in dataclasses.fields(obj):
            if f.name in ("cfar", "cluster", "frame_period_s"):
                continue
            default = getattr(obj, f.name)
            for v in _ODD:
                n = len(default) if isinstance(default, tuple) else 0
                yield table, f.name, [v] * n if n else v


@pytest.fixture(scope="module")
def small_cloud(tmp_path_factory):
    from mmsnap_graph import io
    from mmsnap_graph.sim import SimulationOptions, simulate_recording
    rec = simulate_recording({"S1": (0.0, 0.0, 0.0), "S2": (0.0, 7.0, np.pi)}, "random",
                             SimulationOptions(physics=None, n_targets=1, frame_period_s=0.05),
                             levels=("point_cloud",), n_frames=40, seed=4)
    path = tmp_path_factory.mktemp("fuzz") / "cloud.h5"
    io.write_recording(path, rec)
    return path


def test_toml_mutations_are_rejected_or_processed(small_cloud, tmp_path, capsys):
    import time
    accepted = []
    for table, key, value in _mutations():
        text = f"[{table}]\n{key} = {_toml(value)}\n"
        path = tmp_path / "m.toml"
        path.write_text(text)
        try:
            read_process_config(path)
        except ConfigurationError as exc:
            assert key in str(exc), (text, exc)
            continue
        accepted.append(text)
    # Run ``process`` on a seeded sample of the accepted files: a clean exit
    # code each, within a time bound (no traceback: run_cli lets one through).
    rng = np.random.default_rng(21)
    for i in rng.choice(len(accepted), size=min(8, len(accepted)), replace=False):
        (tmp_path / "a.toml").write_text(accepted[i])
        out = tmp_path / f"out{i}.h5"
        start = time.perf_counter()
        code, _, err = run_cli(capsys, "process", small_cloud, "-o", out, "--no-progress",
                               "--config", tmp_path / "a.toml")
        assert code in (0, 1), (accepted[i], err)
        assert time.perf_counter() - start < 10, accepted[i]


# The table of keys, units and accepted values in docs/TI.md, tried on the code.

_TABLES = ("chain", "chain.cfar", "chain.cluster", "ekf", "scene", "matching")
_INTERVAL = re.compile(r"([\[(])\s*([-+0-9.e]+|pi|[a-z_]+)\s*,\s*([-+0-9.e]+|pi)\s*([\])])")


def _doc_tables() -> dict[str, dict[str, dict[str, str]]]:
    """table -> key -> {default, unit, accepted}, from the docs/TI.md tables
    announced by a line starting with **`[table]`**."""
    lines = (ROOT / "docs" / "TI.md").read_text().splitlines()
    out: dict[str, dict[str, dict[str, str]]] = {}
    for i, line in enumerate(lines):
        m = re.match(r"\*\*`\[([a-z.]+)\]`\*\*", line)
        if not m:
            continue
        header = [c.strip() for c in lines[i + 2].strip("|").split("|")]
        assert header[:4] == ["key", "default", "unit", "accepted"], (m[1], header)
        rows = {}
        for row in lines[i + 4:]:
            if not row.startswith("|"):
                break
            cells = [c.strip() for c in row.strip("|").split("|")]
            rows[cells[0].strip("`")] = dict(zip(header[1:4], cells[1:4]))
        assert m[1] not in out, f"two tables for [{m[1]}]"
        out[m[1]] = rows
    return out


#: Keys whose bound is another key's default.
_OTHERS = {"min_range_m": ChainConfig().min_range_m, "confirm_hits": EkfConfig().confirm_hits}


def _number(text: str) -> float:
    return np.pi if text == "pi" else _OTHERS[text] if text in _OTHERS else float(text)


def _bound_probes(accepted: str, integer: bool) -> list[tuple[object, bool]]:
    """(value, accepted?) pairs at each bound of ``accepted``, just inside and
    just outside, and a NaN (always rejected)."""
    rule = accepted.split(";")[0].strip()
    if rule == "finite":
        return [(0.0, True), (-1e6, True), (float("nan"), False), (float("inf"), False)]
    m = re.fullmatch(r"(integer )?(>=?) (\S+)", rule)
    if m:
        lo = _number(m[3])
        interval = ("[" if m[2] == ">=" else "(", lo, np.inf, ")")
    else:
        m = _INTERVAL.search(rule)
        assert m, f"cannot read {accepted!r}"
        interval = (m[1], _number(m[2]), _number(m[3]), m[4])
    left, lo, hi, right = interval
    step = 1 if integer else max(abs(lo), abs(hi) if np.isfinite(hi) else 0.0, 1.0) * 1e-9
    probes = [(lo, left == "["), (lo - step, False), (lo + step, True)]
    if np.isfinite(hi):
        probes += [(hi, right == "]"), (hi + step, False), (hi - step, True)]
    if integer:
        probes = [(int(v), ok) for v, ok in probes] + [(float(lo) + 0.5, False)]
    else:
        probes.append((float("nan"), False))
    return probes


def _probes(accepted: str, default) -> list[tuple[object, bool]]:
    """Values a key with ``default`` (its TOML value) must accept or reject."""
    if accepted in ("true or false",):
        return [(True, True), (False, True), ("yes", False), (1, False)]
    choices = re.findall(r'"([a-z]+)"', accepted)
    if choices and re.fullmatch(r'("[a-z]+"(, | or )?)+((true|false)(, | or )?)*', accepted):
        extra = [(v, True) for v in (True, False) if str(v).lower() in accepted]
        return [(c, True) for c in choices] + extra + [("nonsense", False)]
    if accepted == "window name":
        return [("hann", True), ("blackman", True), ("no-such-window", False)]
    if isinstance(default, list) or re.match(r"\d+ (values|integers) in", accepted):
        intervals = _INTERVAL.findall(accepted)
        n = int(accepted.split()[0])
        base = list(default) if isinstance(default, list) else [1e-3] * n
        integer = "integers" in accepted
        out = []
        for k in range(n):
            lo_hi = intervals[k] if len(intervals) == n else intervals[0]
            for v, ok in _bound_probes("".join((lo_hi[0], lo_hi[1], ", ", lo_hi[2], lo_hi[3])),
                                       integer):
                out.append((base[:k] + [v] + base[k + 1:], ok))
        return out
    return None


def _configure(table: str, key: str, value):
    parts = table.split(".")
    data = {parts[0]: {parts[1]: {key: value}} if len(parts) > 1 else {key: value}}
    if table == "matching":
        return matching_config_from_mapping(data)
    return process_config_from_mapping(data)


def _defaults() -> dict[str, dict[str, object]]:
    """table -> key -> default as the TOML files print it ("unset" if none)."""
    out = {}
    for text in (process_config_to_toml(ProcessConfig()), matching_config_to_toml(
            MatchingOptions())):
        table = None
        for line in text.splitlines():
            if line.startswith("["):
                table = line.strip("[]")
                out[table] = {}
            elif table and "=" in line:
                key, value = (p.strip() for p in line.lstrip("# ").split("=", 1))
                unset = line.startswith("#")
                out[table][key] = "unset" if unset else value.split("  #")[0].strip()
    return out


def test_the_docs_table_of_keys_lists_every_key_with_its_default():
    doc, code = _doc_tables(), _defaults()
    assert set(doc) == set(_TABLES)
    for table in _TABLES:
        assert list(doc[table]) == list(code[table]), table
        for key, row in doc[table].items():
            assert row["default"].replace(" ", "") == code[table][key].replace(" ", ""), \
                (table, key, row["default"], code[table][key])
            assert row["unit"], (table, key)


@pytest.mark.parametrize("table", _TABLES)
def test_the_docs_accepted_values_are_what_the_code_accepts(table):
    """Each bound of docs/TI.md's table, just inside and just outside, through
    the TOML route: a rejected value is a ConfigurationError (ValidationError
    for [matching]) naming the key. Before: the page listed no ranges."""
    doc = _doc_tables()[table]
    tried = 0
    for key, row in doc.items():
        default = tomllib.loads(f"v = {_defaults()[table][key]}")["v"] \
            if row["default"] != "unset" else None
        integer = row["accepted"].startswith("integer")
        probes = _probes(row["accepted"], default)
        if probes is None:
            probes = _bound_probes(row["accepted"], integer)
        for value, ok in probes:
            tried += 1
            if ok:
                _configure(table, key, value)
                continue
            with pytest.raises((ConfigurationError, ValidationError), match=re.escape(key)):
                _configure(table, key, value)
    assert tried >= 3 * len(doc)


def _numeric_keys():
    """(table path, key, default) of every number (or array of numbers) a
    ``mmsnap process`` file may set."""
    from mmsnap_graph.radar.scene import SceneConfig

    tables = {("chain",): ChainConfig, ("chain", "cfar"): CfarConfig,
              ("chain", "cluster"): ClusterConfig, ("ekf",): EkfConfig, ("scene",): SceneConfig}
    for path, cls in tables.items():
        for f in dataclasses.fields(cls):
            default = f.default_factory() if f.default is dataclasses.MISSING else f.default
            number = isinstance(default, (int, float)) and not isinstance(default, bool)
            unset = default is None and str(f.type).startswith(("float", "int"))
            numbers = isinstance(default, tuple) and all(isinstance(v, (int, float))
                                                          for v in default)
            if (number or unset or numbers) and f.name != "frame_period_s":
                yield path, f.name, default


NUMERIC_KEYS = list(_numeric_keys())


@pytest.mark.parametrize("value", ["inf", "-inf", "nan", "1e308", "-1e308"])
def test_every_number_of_the_process_file_is_bounded_and_finite(tmp_path, value):
    """Before: `[chain] max_range_m = inf` (or 1e308) passed the check and
    `mmsnap process` crashed with OverflowError in the chain; 1e308 passed for
    dealias_min_snr_db, adc_full_scale and four clustering options. Every key
    set to a non-finite or absurd value is a ConfigurationError naming it."""
    assert len(NUMERIC_KEYS) > 40
    for path, key, default in NUMERIC_KEYS:
        text = value if not isinstance(default, tuple) else \
            "[" + ", ".join([value] * len(default)) + "]"
        cfg = tmp_path / "bounds.toml"
        cfg.write_text(f"[{'.'.join(path)}]\n{key} = {text}\n")
        with pytest.raises(ConfigurationError, match=key) as info:
            read_process_config(cfg)
        assert "bounds.toml" in str(info.value), (path, key, value)


def test_matching_durations_beyond_any_recording_are_clipped_not_refused(tmp_path):
    """[matching] (mmsnap calibrate) refuses non-finite values; a huge finite
    one (1e308 s) is clipped to the recording's frames (MatchingOptions)."""
    for value in ("inf", "nan"):
        cfg = tmp_path / "m.toml"
        cfg.write_text(f"[matching]\nmax_lag_s = {value}\n")
        with pytest.raises(ConfigurationError, match="max_lag_s"):
            read_matching_config(cfg)
    cfg.write_text("[matching]\nmax_lag_s = 1e308\n")
    assert read_matching_config(cfg).frame_counts(0.05)[0] > 10 ** 6
