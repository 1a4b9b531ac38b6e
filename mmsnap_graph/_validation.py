"""Input checks for the public boundary.

Each helper takes the argument's *name* so the error names the field and the
offending value.
"""

from __future__ import annotations

import bisect
import functools
import json
import math
from typing import Any, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .errors import MmsnapError, ValidationError

__all__ = [
    "as_float_array",
    "check_count",
    "check_finite",
    "check_positive",
    "check_probability",
    "check_shape",
    "chi2_gate",
    "frame_steps",
    "outlying_frames",
    "frozen_vector",
    "int_array",
    "parse_json",
    "positive_scalar",
    "short_repr",
]


def as_float_array(value: ArrayLike, name: str) -> NDArray:
    """``np.asarray(value, float)`` with a clear error for non-numeric input
    (an integer beyond the float range, ``10**400``, included)."""
    try:
        return np.asarray(value, dtype=float)
    except (TypeError, ValueError, OverflowError) as exc:
        raise ValidationError(f"{name} must be numeric (finite floats), got "
                              f"{short_repr(value)}") from exc


def short_repr(value: Any) -> str:
    """``repr(value)`` for a message: numpy values as the plain numbers and
    lists they hold (``0.5``, ``[0.0, 0.0]``, not ``np.float64(0.5)`` or
    ``array([0., 0.])``), cut to 80 characters (a 400-digit number)."""
    if isinstance(value, (np.ndarray, np.generic)):
        value = value.tolist()
    text = repr(value)
    return text if len(text) <= 80 else text[:60] + f"... ({len(text)} characters)"


def _json_integer(text: str) -> int | float:
    """A JSON integer: a Python int while a float can hold it; beyond (more
    than 300 digits: ``10**400``) the float of it, ``inf``, which the
    readers' finiteness checks refuse by name (an int there would raise
    ``OverflowError`` at the first ``float()``, and Python refuses to parse
    one of more than 4300 digits)."""
    return int(text) if len(text) <= 300 else float(text)


def parse_json(text: str) -> Any:
    """``json.loads(text)`` with integers beyond the float range read as
    ``inf`` (:func:`_json_integer`); the one JSON parser of the readers."""
    return json.loads(text, parse_int=_json_integer)


def check_shape(arr: NDArray, shape: Sequence[int | None], name: str) -> NDArray:
    """Check ``arr.shape`` against ``shape`` (``None`` matches any length)."""
    if arr.ndim != len(shape) or any(
        want is not None and got != want for got, want in zip(arr.shape, shape)
    ):
        want_txt = "(" + ", ".join("N" if s is None else str(s) for s in shape) + ")"
        raise ValidationError(f"{name} must have shape {want_txt}, got {arr.shape}")
    return arr


def check_finite(arr: NDArray, name: str) -> NDArray:
    """Reject NaN and infinity, naming the first offending entry."""
    ok = np.isfinite(arr)
    if ok.all():  # the method: np.all's dispatch costs as much again on small arrays
        return arr
    idx = tuple(int(i) for i in np.argwhere(~ok)[0])
    raise ValidationError(f"{name} must be finite, got {arr[idx]!r} at index {idx}")


def check_positive(value: ArrayLike, name: str, *, strict: bool = True) -> NDArray:
    """Reject values that are not (strictly) positive, or not finite."""
    arr = check_finite(as_float_array(value, name), name)
    bad = arr <= 0 if strict else arr < 0
    if np.any(bad):
        idx = tuple(int(i) for i in np.argwhere(np.atleast_1d(bad))[0])
        got = np.atleast_1d(arr)[idx]
        rel = "> 0" if strict else ">= 0"
        raise ValidationError(f"{name} must be {rel}, got {got!r}")
    return arr


def positive_scalar(value: object, name: str) -> float:
    """``value`` as a float when it is one finite number > 0 (not a bool, a
    string, a list or an array); else :class:`ValidationError` naming it."""
    ok = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(
        value, (bool, np.bool_))
    try:
        v = float(value) if ok else math.nan
    except OverflowError:  # an int beyond the float range
        v = math.inf
    if not (math.isfinite(v) and v > 0):
        raise ValidationError(f"{name} must be one finite number > 0, got {short_repr(value)}")
    return v


def frozen_vector(value: ArrayLike, name: str, length: int) -> NDArray:
    """A read-only copy of a finite float vector of shape ``(length,)``."""
    arr = check_finite(as_float_array(value, name), name)
    if arr.shape != (length,):
        raise ValidationError(f"{name} must have shape ({length},), got {arr.shape}")
    arr = np.array(arr, dtype=float)
    arr.setflags(write=False)
    return arr


def int_array(value: ArrayLike, name: str) -> NDArray:
    """A 1-D int64 copy of ``value``; floats must hold whole numbers. Raises
    :class:`ValidationError` naming ``name``."""
    arr = np.asarray(value)
    if arr.ndim != 1:
        raise ValidationError(f"{name} must be 1-D, got shape {arr.shape}")
    if arr.size and arr.dtype.kind not in "iubf":
        raise ValidationError(f"{name} must hold integers, got dtype {arr.dtype}")
    if arr.size and arr.dtype.kind == "f":
        if not np.all(np.isfinite(arr)) or not np.all(arr == np.round(arr)):
            raise ValidationError(f"{name} must hold integers, got dtype {arr.dtype}")
        if np.any(np.abs(arr) >= 2.0 ** 63):
            raise ValidationError(f"{name} must fit in int64, got {arr[np.abs(arr) >= 2.0 ** 63][0]:g}")
    if arr.size and arr.dtype.kind == "u" and np.any(arr > np.iinfo(np.int64).max):
        raise ValidationError(f"{name} must fit in int64, got {arr[arr > np.iinfo(np.int64).max][0]}")
    return arr.astype(np.int64)


def check_pose(value: ArrayLike, name: str) -> NDArray:
    """``value`` as a finite (3,) pose ``(x_m, y_m, phi_rad)``; a heading
    beyond 2 pi in magnitude is taken for degrees (the most common unit
    mistake: 180 degrees read as 180 rad still "fits"), a ValidationError
    naming ``name``."""
    pose = check_finite(check_shape(as_float_array(value, name), (3,), name), name)
    check_heading(float(pose[2]), name)
    return pose


def check_heading(phi: float, name: str) -> float:
    """``phi`` when ``|phi| <= 2 pi``; else a ValidationError saying radians."""
    if abs(phi) > 2.0 * math.pi + 1e-9:
        raise ValidationError(f"{name}: heading phi={phi:g} is beyond 2 pi: headings are in "
                              f"radians (if {phi:g} is degrees, give {math.radians(phi):.6g})")
    return phi


def check_count(value: object, name: str, minimum: int = 1, maximum: int | None = None, *,
                error: type[MmsnapError] = ValidationError) -> int:
    """``value`` as an int in ``[minimum, maximum]``: a Python or numpy
    integer, not a bool, a float or a string (a float count is most often a
    unit or parsing mistake). Raises ``error`` (default ValidationError)
    naming ``name`` and the value."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise error(f"{name}={value!r} must be an integer, got {type(value).__name__}")
    if value < minimum or (maximum is not None and value > maximum):
        span = f">= {minimum}" if maximum is None else f"in [{minimum}, {maximum}]"
        raise error(f"{name}={value!r} must be an integer {span}")
    return int(value)


def check_probability(value: object, name: str, *,
                      error: type[MmsnapError] = ValidationError) -> float:
    """``value`` as a float strictly inside ``(0, 1)`` (a gate or confidence
    probability: 0 and 1 make an empty or an infinite gate). Raises ``error``
    naming ``name`` and the value."""
    if isinstance(value, (bool, np.bool_, str)) or not isinstance(
            value, (int, float, np.integer, np.floating)):
        raise error(f"{name} must be a number in (0, 1), got {value!r}")
    p = float(value)
    if not 0.0 < p < 1.0:
        raise error(f"{name} must be in (0, 1), got {value!r}")
    return p


def chi2_gate(gate_probability: float, dof: ArrayLike, *, name: str = "gate_probability"):
    """The chi-square gate that keeps a fraction ``gate_probability`` of
    consistent residuals: ``chi2.ppf(gate_probability, dof)``, a squared
    Mahalanobis distance with ``dof`` degrees of freedom.

    Every chi-square gate of the library is given this way, as the
    probability of *keeping* a consistent residual (0.999 keeps 99.9%),
    never as the outlier tail ``1 - p``. ``dof`` may be an array (one gate
    per row); returns a float for a scalar ``dof``, an array otherwise.
    """
    p = check_probability(gate_probability, name)
    d = np.asarray(dof, dtype=float)
    if d.size == 0 or not np.all(np.isfinite(d)) or np.any(d <= 0):
        raise ValidationError(f"dof must be > 0, got {dof!r}")
    if d.ndim == 0 and d == 2.0:
        return -2.0 * math.log1p(-p)  # closed form, and no scipy on a light path
    if d.ndim == 0:
        return _chi2_ppf(p, float(d))
    from scipy.stats import chi2  # deferred: scipy.stats is slow to import

    return chi2.ppf(p, d)


@functools.lru_cache(maxsize=256)
def _chi2_ppf(p: float, dof: float) -> float:
    """``chi2.ppf(p, dof)`` of one gate, kept: the checks ask for the same few
    gates every frame, and scipy takes a fraction of a millisecond each."""
    from scipy.stats import chi2  # deferred: scipy.stats is slow to import

    return float(chi2.ppf(p, dof))


_INT64_MAX = np.uint64(2**63 - 1)
_INT64_MAX_INT = 2**63 - 1


def frame_steps(frames: ArrayLike) -> NDArray:
    """``np.diff`` of int64 frame numbers without wrapping: frames at both
    ends of int64 are up to ``2^64 - 1`` apart, which ``np.diff`` turns into
    a negative step; here each step is exact, saturated to +-``2^63 - 1``.
    frames : (n,) int; returns (n - 1,) int64."""
    f = np.asarray(frames, dtype=np.int64).ravel()
    if f.size < 2 or int(f.max()) - int(f.min()) <= _INT64_MAX_INT:
        return np.diff(f)  # no step can wrap: np.diff is exact
    a, b = f[:-1].view(np.uint64), f[1:].view(np.uint64)
    up = f[1:] >= f[:-1]
    size = np.minimum(np.where(up, b - a, a - b), _INT64_MAX).astype(np.int64)
    return np.where(up, size, -size)


#: At most this share of a log's rows may be outlying frame numbers (more:
#: the table is not in frame order, or the clock jumped; nothing is dropped).
OUTLIER_SHARE = 0.01
#: A gap this many frames wide (and 100 median steps) cuts off a first or
#: last block of frames.
OUTLIER_GAP_FRAMES = 1000


def _in_order(frames: NDArray) -> NDArray:
    """(n,) bool: the rows of a longest non-decreasing run of ``frames`` in
    row order (patience sorting, O(n log n))."""
    tails: list[int] = []          # frame value ending the best run of each length
    ends: list[int] = []           # row index of that end
    prev = np.full(frames.size, -1)
    for i, f in enumerate(frames.tolist()):
        k = bisect.bisect_right(tails, f)
        if k == len(tails):
            tails.append(f)
            ends.append(i)
        else:
            tails[k], ends[k] = f, i
        prev[i] = ends[k - 1] if k else -1
    keep = np.zeros(frames.size, bool)
    i = ends[-1] if ends else -1
    while i >= 0:
        keep[i] = True
        i = prev[i]
    return keep


def outlying_frames(frames: ArrayLike) -> NDArray:
    """(n,) bool: the rows of one log (in file order) whose frame numbers are
    out of line with the others, so that they must not set its frame clock's
    origin or span: a few rows (at most :data:`OUTLIER_SHARE`) that break the
    frames' order (``..., 49, 50, -5, 51, ...``), and a first or last block
    of a few rows cut off by a gap of more than :data:`OUTLIER_GAP_FRAMES`
    frames and 100 median steps (``-2**40`` before frames 0-99). A table
    that is not in frame order, or whose clock really jumps, has none."""
    f = np.asarray(frames, dtype=np.int64).ravel()
    out = np.zeros(f.size, bool)
    few = max(1, int(OUTLIER_SHARE * f.size))
    if f.size < 3:
        return out
    if np.any(f[1:] < f[:-1]):
        off = ~_in_order(f)
        if np.count_nonzero(off) > few:
            return out                     # not a log in frame order
        out |= off
    distinct = np.unique(f[~out])
    if distinct.size < 3:
        return out
    steps = frame_steps(distinct)
    wide = np.flatnonzero(steps > max(OUTLIER_GAP_FRAMES, 100 * float(np.median(steps))))
    if wide.size:
        for block in (f <= distinct[wide[0]], f >= distinct[wide[-1] + 1]):
            block &= ~out
            if np.count_nonzero(block) <= few:
                out |= block
    return out
