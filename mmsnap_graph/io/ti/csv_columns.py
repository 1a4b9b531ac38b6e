"""A fast path for plain CSV point logs: columns parsed by NumPy over the
bytes of the file, with no Python object per cell.

:func:`plain_csv_columns` reads the common case of a logger's table: a header
line, then rows of the same number of comma-separated cells, no quotes, no
blank or ``#`` lines, ``\\n`` or ``\\r\\n`` line ends. It returns None for any
other text, so that the general reader
(:func:`mmsnap_graph.io.ti.point_table.read_point_tables`) handles it with its
own rules and error messages; where it returns columns, they equal the
general reader's bit for bit (tests/io/ti/test_csv_columns.py).

Numbers: a cell ``[-]digits[.digits]`` with at most 2^53 as its digits
(mantissa) and at most 22 decimals is ``mantissa / 10**decimals`` computed in
float64: both are exact, so the quotient is the correctly rounded value, as
Python's ``float`` gives (Clinger's fast path). Any other cell of a numeric
column (an exponent, ``nan``, spaces, more digits) goes through ``float``.
"""

from __future__ import annotations

import re

import numpy as np
from numpy.typing import NDArray

__all__ = ["plain_csv_columns"]

#: Rows parsed at a time: bounds the per-byte work arrays (about 30 bytes of
#: work per byte of text) whatever the file's size.
CHUNK_ROWS = 1 << 16
_COMMA, _NEWLINE, _DOT, _MINUS = 44, 10, 46, 45
#: Text the general reader splits or skips differently: other line breaks
#: (``str.splitlines``), quotes (the csv module), NUL, comment lines.
_UNUSUAL = '"\r\x00\x0b\x0c\x1c\x1d\x1e\x85\u2028\u2029'
_COMMENT = re.compile(r"(?:^|\n)[^\S\n]*#")
_EXACT_MANTISSA = float(2 ** 53)
#: Longest field read by the fast path (longer ones go through ``float``).
MAX_WIDTH = 32
_POW10 = 10.0 ** np.arange(23)
#: Longest text cell read by the fast path.
MAX_TEXT = 256


def _is_number(cell: str) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return True


def _decimals(chunk: NDArray, starts: NDArray, ends: NDArray) -> tuple[NDArray, NDArray]:
    """Values of the fields ``chunk[starts[i]:ends[i]]`` read as
    ``[-]digits[.digits]``, and a mask of the fields that are not of that
    form or not exact that way (their value is then meaningless).

    Horner's scheme over the fields' characters, all fields at once: the
    fields are right-aligned at W columns (W the longest, at most
    :data:`MAX_WIDTH`), column k holding each field's k-th character from
    the right-aligned start (nothing where a field is shorter)."""
    n, length = starts.size, ends - starts
    width = int(min(length.max(initial=1), MAX_WIDTH))
    lead = width - length                         # empty columns before each field
    mantissa = np.zeros(n)
    n_digits, n_dots, n_minus = (np.zeros(n, np.int8) for _ in range(3))
    point = np.full(n, width - 1, np.int8)        # the decimal point's column (none: the last)
    bad = (length > width) | (length == 0)
    for k in range(width):
        code = chunk.take(ends - (width - k), mode="clip") - 48      # uint8: wraps below "0"
        inside = lead <= k
        digit, dot = (code < 10) & inside, (code == (_DOT - 48) % 256) & inside
        minus = (code == (_MINUS - 48) % 256) & inside
        bad |= (inside & ~(digit | dot | minus)) | (minus & (lead != k))
        n_digits += digit
        n_dots += dot
        n_minus += minus
        point[dot] = k
        # Exact while below 2^53 (checked after); rounding is monotone above.
        mantissa = np.where(digit, mantissa * 10.0 + code, mantissa)
    decimals = (width - 1 - point.astype(np.int64))     # digits after the point
    bad |= (n_digits == 0) | (n_dots > 1) | (n_minus > 1) | (mantissa >= _EXACT_MANTISSA) \
        | (decimals > 22)
    value = mantissa / _POW10[np.minimum(decimals, 22)]
    return np.where(n_minus > 0, -value, value), bad


def _strings(chunk: NDArray, starts: NDArray, ends: NDArray) -> NDArray | None:
    """The fields as stripped str (as the general reader keeps text cells),
    or None for a field longer than :data:`MAX_TEXT` bytes."""
    width = int((ends - starts).max(initial=1))
    if width > MAX_TEXT:
        return None
    index = starts[:, None] + np.arange(width)
    raw = np.where(index < ends[:, None], chunk.take(index, mode="clip"), 0).astype(np.uint8)
    cells = raw.view(f"S{width}").ravel()
    if raw.max(initial=0) >= 128:                 # UTF-8 beyond ASCII
        return np.char.strip(np.char.decode(cells, "utf-8"))
    text = cells.astype(str)
    return np.char.strip(text) if np.any((raw > 0) & (raw <= 32)) else text


def _chunk_columns(data: bytes, lo: int, hi: int, n_cols: int, numeric: list[bool]
                   ) -> list[NDArray] | None:
    """The columns of the rows in ``data[lo:hi]`` (whole lines), or None."""
    chunk = np.frombuffer(data, np.uint8, hi - lo, lo)
    ends = np.flatnonzero((chunk == _COMMA) | (chunk == _NEWLINE))
    if ends.size % n_cols or not ends.size:
        return None
    shape = ends.reshape(-1, n_cols)
    if np.any(chunk[shape[:, -1]] != _NEWLINE) or np.any(chunk[shape[:, :-1]] != _COMMA):
        return None                                  # a row with more or fewer cells
    starts = np.concatenate([[0], ends[:-1] + 1])
    out = []
    for j in range(n_cols):
        s, e = starts[j::n_cols], ends[j::n_cols]
        if not numeric[j]:
            out.append(_strings(chunk, s, e))
            if out[-1] is None:
                return None
            continue
        col, bad = _decimals(chunk, s, e)
        wrong = np.flatnonzero(bad)
        for i in wrong:
            try:
                col[i] = float(data[lo + s[i]:lo + e[i]].decode("utf-8"))
            except (ValueError, UnicodeDecodeError):
                return None                          # text in a numeric column: general rules
        out.append(col)
    return out


def plain_csv_columns(text: str) -> dict[str, NDArray] | None:
    """name -> column of a plain CSV table (module docstring), or None when
    the text needs the general reader: a float64 column where the first row's
    cell is a number, else a column of stripped strings."""
    if "\r" in text:
        text = text.replace("\r\n", "\n")
    if any(c in text for c in _UNUSUAL) or ("#" in text and _COMMENT.search(text)) \
            or "\n\n" in text:
        return None
    if not text.endswith("\n"):
        text += "\n"
    head = text.find("\n")
    names = [c.strip() for c in text[:head].split(",")]
    cells = text[head + 1:text.find("\n", head + 1)].split(",")
    if len(names) < 2 or len(cells) != len(names) or len(set(names)) < len(names) \
            or any(not c.strip() for c in cells):
        return None
    numeric = [_is_number(c) for c in cells]
    data = text.encode("utf-8")
    start = len(text[:head].encode("utf-8")) + 1
    line_ends = start + np.flatnonzero(np.frombuffer(data, np.uint8, offset=start) == _NEWLINE)
    bounds = [start, *(line_ends[CHUNK_ROWS - 1::CHUNK_ROWS] + 1).tolist()]
    if bounds[-1] != len(data):
        bounds.append(len(data))
    parts = []
    for lo, hi in zip(bounds[:-1], bounds[1:]):
        columns = _chunk_columns(data, lo, hi, len(names), numeric)
        if columns is None:
            return None
        parts.append(columns)
    return {name: np.concatenate([p[j] for p in parts]) for j, name in enumerate(names)}
