"""Robust kernels of the measurement factors: one set of defaults.

The tuning constants act on the whitened residual (unit variance under the
Gaussian model): Huber 1.345 (95% efficiency under Gaussian noise), Cauchy
2.5. The GTSAM noise models (:func:`factors.gtsam_factors.measurement_noise`)
and the calibration presolver use these.
"""

from __future__ import annotations

__all__ = ["ROBUST_KERNELS", "ROBUST_K_DEFAULT", "robust_k"]

#: The robust kernels the project supports (``None`` = Gaussian).
ROBUST_KERNELS = ("huber", "cauchy")

#: Default tuning constant of each kernel, on the whitened residual.
ROBUST_K_DEFAULT = {"huber": 1.345, "cauchy": 2.5}


def robust_k(robust: str, k: float | None = None) -> float:
    """The tuning constant of kernel ``robust``: ``k`` if given, else
    :data:`ROBUST_K_DEFAULT`. Raises ``ValueError`` naming an unknown kernel."""
    if robust not in ROBUST_K_DEFAULT:
        raise ValueError(f"robust={robust!r} must be None, 'huber' or 'cauchy'")
    return float(ROBUST_K_DEFAULT[robust] if k is None else k)
