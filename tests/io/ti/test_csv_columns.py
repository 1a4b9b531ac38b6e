"""The fast path of the CSV point-table reader (mmsnap_graph.io.ti.csv_columns):
equal bit for bit to the general reader where it answers, None where the
general reader's rules are needed, and lighter in memory."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

from mmsnap_graph.io.ti import csv_columns
from mmsnap_graph.io.ti.csv_columns import plain_csv_columns
from mmsnap_graph.io.ti.point_table import csv_text_columns, read_point_tables

from _shared import DATA, ROOT

#: Number spellings the fast path reads itself or hands to ``float``: signs,
#: no integer or no fraction part, leading zeros, 15-17 significant digits,
#: more than 22 decimals, exponents, nan/inf, spaces, fields over MAX_WIDTH.
ODD_NUMBERS = ["0", "-0", "-0.0", "007", ".5", "-.5", "5.", "-5.", "+1.5", "1e3", "-2.5E-3",
               "nan", "-inf", " 1.25", "3.5 ", "123456789012345", "1234567890123456",
               "12345678901234567", "9007199254740993", "0.1000000000000000055511151231257827",
               "1." + "0" * 25 + "1", "-" + "9" * 40, "1700000000.050000", "  -0.000001  ",
               "1_0", "\u0661\u0662"]


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    if a.dtype != b.dtype or a.shape != b.shape:
        return False
    if a.dtype.kind == "f":
        return np.array_equal(a.view(np.int64), b.view(np.int64))
    return np.array_equal(a, b)


def _random_table(rng: np.random.Generator, rows: int) -> str:
    names = rng.choice(["S1", "S2", " radar B ", "nœud-3"], rows)
    cols = [rng.normal(0, 10.0 ** rng.integers(-3, 6, rows)), rng.integers(-10**6, 10**6, rows),
            rng.random(rows)]
    odd = rng.choice(ODD_NUMBERS, rows)
    use_odd = rng.random(rows) < 0.2
    lines = ["node,a,frame, b ,c"]
    for i in range(rows):
        a = odd[i] if use_odd[i] else f"{cols[0][i]:.{rng.integers(0, 18)}f}"
        c = repr(float(cols[2][i])) if i % 3 else f"{cols[2][i]:.9g}"
        lines.append(f"{names[i]},{a},{cols[1][i]},{cols[0][i] * 1e-3:.6f},{c}")
    return "\n".join(lines) + ("\n" if rows % 2 else "")


@pytest.mark.parametrize("seed", range(4))
def test_the_fast_path_equals_the_general_reader_bit_for_bit(seed, monkeypatch):
    # Small chunks: the rows cross several chunk boundaries.
    monkeypatch.setattr(csv_columns, "CHUNK_ROWS", 97)
    text = _random_table(np.random.default_rng(seed), 1500)
    fast = plain_csv_columns(text)
    assert fast is not None
    general = csv_text_columns(text, "table.csv", fast=False)
    assert list(fast) == list(general) == ["node", "a", "frame", "b", "c"]
    for name in general:
        assert _same(fast[name], general[name]), name


def test_every_odd_spelling_reads_as_python_float_reads_it():
    text = "frame,x\n" + "".join(f"{i},{v}\n" for i, v in enumerate(ODD_NUMBERS))
    x = plain_csv_columns(text)["x"]
    expected = np.array([float(v) for v in ODD_NUMBERS])
    assert _same(x, expected)


@pytest.mark.parametrize("text", [
    'frame,x\n0,"1.5"\n',              # quotes: the csv module's rules
    "frame,x\n# a comment\n0,1\n",     # comment lines are skipped
    "frame,x\n0,1\n\n1,2\n",           # blank lines are skipped
    "frame,x\n0,1\n1,2,3\n",           # a ragged row: the general error names its line
    "frame,x\n0,1\n1,\n",              # an empty cell is NaN
    "frame,x\n0,1\n1,abc\n",           # text in a numeric column
    "frame,frame\n0,1\n",              # duplicate names: the general error
    "frame\n0\n",                      # one column
    "frame,x\n",                       # no rows
    "frame,x\n0,1\x0c\n",              # a line break for str.splitlines
    "frame,node\n0," + "n" * 300 + "\n",
])
def test_anything_else_is_left_to_the_general_reader(text):
    assert plain_csv_columns(text) is None


def test_the_shipped_logs_take_the_fast_path():
    paths = [DATA / "ti" / "points_room_frame.csv", *sorted(
        (ROOT / "data" / "real" / "darksz").glob("*.csv"))]
    assert len(paths) >= 3
    for path in paths:
        text = path.read_text(encoding="utf-8-sig")
        fast = plain_csv_columns(text)
        assert fast is not None, path
        general = csv_text_columns(text, path, fast=False)
        assert all(_same(fast[k], general[k]) for k in general), path


def test_reading_a_log_needs_less_than_500_bytes_a_row(tmp_path):
    """Before: about 1,040 bytes of Python allocations per row at its peak
    (a list of cells per row); the fast path keeps the text, its bytes and
    the columns (benchmarks/bench_point_table.py measures it at larger sizes)."""
    rng = np.random.default_rng(0)
    rows = 20_000
    frame = np.sort(rng.integers(0, rows // 16, rows))
    xyz = rng.normal(0, 2, (rows, 4))
    path = tmp_path / "log.csv"
    path.write_text("node,frame,x,y,z,doppler\n" + "".join(
        f"S{1 + i % 2},{frame[i]},{xyz[i, 0]:.6f},{xyz[i, 1]:.6f},{xyz[i, 2]:.6f},"
        f"{xyz[i, 3]:.6f}\n" for i in range(rows)))
    tracemalloc.start()
    try:
        clouds = read_point_tables(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert sum(c.x_m.size for c in clouds.values()) == rows
    assert peak / rows < 500, peak / rows


def test_mutated_tables_read_equal_or_go_to_the_general_reader():
    """Seeded fuzz: 600 single-character edits of a small plain log (signs,
    points, digits, letters, separators, quotes, spaces, non-ASCII): the fast
    path never raises, and where it answers it equals the general reader."""
    rng = np.random.default_rng(7)
    base = _random_table(np.random.default_rng(1), 12)
    alphabet = list("0123456789.-+eE,\n \t\"#_xS") + ["\u00e9", "\u0661", "\r\n", ""]
    answered = 0
    for _ in range(600):
        text = base
        for _ in range(rng.integers(1, 4)):
            i = int(rng.integers(0, len(text)))
            edit = str(rng.choice(alphabet))
            text = text[:i] + edit + text[i + int(rng.integers(0, 2)):]
        fast = plain_csv_columns(text)
        if fast is None:
            continue
        answered += 1
        try:
            general = csv_text_columns(text, "fuzz.csv", fast=False)
        except Exception:  # noqa: BLE001 - the general reader refuses: so must the fast path
            pytest.fail(f"the fast path read a table the general reader refuses: {text!r}")
        assert list(fast) == list(general), text
        for name in general:
            assert _same(fast[name], general[name]), (name, text)
    assert answered > 100
