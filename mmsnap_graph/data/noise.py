"""Noise and prior parameters shared by every estimator: the standard
deviations of one node's measurements and the Gaussian prior on a target state.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from ..errors import ValidationError
from .._validation import frozen_vector

__all__ = ["MeasurementNoise", "GaussianPrior"]


@dataclass(frozen=True, kw_only=True, slots=True)
class MeasurementNoise:
    """Standard deviations of one node's measurements (paper eq. 14; its
    resolutions by default).

    range_m : float, metres (0.035: Table I's range resolution).
    omega_rad : float, spatial frequency in radians (pi / 4).
    doppler_mps : float, radial velocity in m/s (0.1807).
    """

    range_m: float = 0.035
    omega_rad: float = np.pi / 4
    doppler_mps: float = 0.1807

    def __post_init__(self) -> None:
        for name in ("range_m", "omega_rad", "doppler_mps"):
            value = getattr(self, name)
            try:
                value = float(value)
            except (TypeError, ValueError) as exc:
                raise ValidationError(f"noise {name} must be a number, got {value!r}") from exc
            if not (math.isfinite(value) and value > 0.0):
                raise ValidationError(f"noise {name} must be finite and > 0, got {value!r}")
            object.__setattr__(self, name, value)

    @property
    def sigmas(self) -> NDArray:
        """(3,) float: ``(range_m, omega_rad, doppler_mps)``, measurement order."""
        return np.array([self.range_m, self.omega_rad, self.doppler_mps])


@dataclass(frozen=True, kw_only=True, slots=True)
class GaussianPrior:
    """Independent Gaussian prior on ``(x_m, y_m, vx_mps, vy_mps)`` (paper eq. 16).

    mean : (4,) float, global frame (default zeros, the paper's).
    sigmas : (4,) float, > 0 (default the paper's ``(3 m, 3 m, 3.5 m/s, 3.5 m/s)``).
    """

    mean: NDArray = field(default_factory=lambda: np.zeros(4))
    sigmas: NDArray = field(default_factory=lambda: np.array([3.0, 3.0, 3.5, 3.5]))

    def __post_init__(self) -> None:
        object.__setattr__(self, "mean", frozen_vector(self.mean, "prior mean", 4))
        sigmas = frozen_vector(self.sigmas, "prior sigmas", 4)
        if np.any(sigmas <= 0.0):
            raise ValidationError(f"prior sigmas must be > 0, got {sigmas.tolist()}")
        object.__setattr__(self, "sigmas", sigmas)

    @property
    def information(self) -> NDArray:
        """(4, 4) float: the prior's information matrix ``diag(1 / sigmas^2)``."""
        return np.diag(1.0 / self.sigmas**2)
