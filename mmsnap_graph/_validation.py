"""Input checks for the public boundary.

Each helper takes the argument's *name* so the error names the field and the
offending value.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .errors import ValidationError

__all__ = ["as_float_array", "check_finite", "check_positive", "check_shape", "frozen_vector", "int_array"]


def as_float_array(value: ArrayLike, name: str) -> NDArray:
    """``np.asarray(value, float)`` with a clear error for non-numeric input."""
    try:
        return np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValidationError(f"{name} must be numeric, got {value!r}") from exc


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
    bad = ~np.isfinite(arr)
    if np.any(bad):
        idx = tuple(int(i) for i in np.argwhere(bad)[0])
        raise ValidationError(f"{name} must be finite, got {arr[idx]!r} at index {idx}")
    return arr


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
