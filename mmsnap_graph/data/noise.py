"""Noise and prior parameters shared by every estimator: the standard
deviations of one node's measurements (:class:`MeasurementNoise`), what a
recording's data say about them (:class:`NodeNoiseEstimate`,
:class:`NoiseEstimate`, made by
:func:`mmsnap_graph.calibration.noise.estimate.estimate_noise`) and the
Gaussian prior on a target state.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping

import numpy as np
from numpy.typing import NDArray

from ..errors import ValidationError
from .._validation import frozen_vector

__all__ = ["MeasurementNoise", "NodeNoiseEstimate", "NoiseEstimate", "GaussianPrior",
           "NOISE_COMPONENTS", "NOISE_METADATA_KEYS", "declared_noise"]

#: Names of the three sigmas, in measurement order.
NOISE_COMPONENTS = ("range_m", "omega_rad", "doppler_mps")
#: The metadata keys of the centroid sigmas a recording declares (the
#: simulator writes them), in measurement order.
NOISE_METADATA_KEYS = ("centroid_range_std_m", "centroid_omega_std_rad",
                       "centroid_doppler_std_mps")


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


def declared_noise(metadata: Mapping) -> "MeasurementNoise | None":
    """The centroid noise a recording's ``metadata`` declare
    (:data:`NOISE_METADATA_KEYS`), or None when a key is missing or a value
    is not a finite number > 0."""
    try:
        return MeasurementNoise(**{name: float(metadata[key])
                                   for name, key in zip(NOISE_COMPONENTS, NOISE_METADATA_KEYS)})
    except (KeyError, TypeError, ValueError, ValidationError):
        return None


def _flags(value, name: str) -> tuple[bool, bool, bool]:
    flags = tuple(bool(v) for v in value)
    if len(flags) != 3:
        raise ValidationError(f"{name} must hold 3 values (range, omega, doppler), got {value!r}")
    return flags


@dataclass(frozen=True, kw_only=True, slots=True)
class NodeNoiseEstimate:
    """What one node's data say about its measurement noise.

    noise : the sigmas to use: the estimate of each identified component,
        the fallback's value (:attr:`NoiseEstimate.fallback`) for the others.
    identified : (3,) bool per component (range, omega, doppler): True when
        ``noise`` holds the data's estimate, False when it holds the fallback.
    n_residuals : (3,) int, residuals the estimate of each component used
        (0 when not identified).
    method : how the identified components were estimated (e.g.
        ``"network+temporal"``; :mod:`mmsnap_graph.calibration.noise.estimate`).
    reasons : (3,) str, why each unidentified component is not (``""`` when
        identified).
    tail_factors : (3,) float >= 1, the factor each sigma was raised by so
        that its variance covers the residuals' heavy tails (1.0: none;
        :mod:`mmsnap_graph.calibration.noise.tails`).
    """

    noise: MeasurementNoise
    identified: tuple[bool, bool, bool]
    n_residuals: tuple[int, int, int]
    method: str
    reasons: tuple[str, str, str] = ("", "", "")
    tail_factors: tuple[float, float, float] = (1.0, 1.0, 1.0)

    def __post_init__(self) -> None:
        if not isinstance(self.noise, MeasurementNoise):
            raise ValidationError(f"noise must be a MeasurementNoise, got {self.noise!r}")
        object.__setattr__(self, "identified", _flags(self.identified, "identified"))
        counts = tuple(int(v) for v in self.n_residuals)
        if len(counts) != 3 or min(counts) < 0:
            raise ValidationError(f"n_residuals must be 3 integers >= 0, got {self.n_residuals!r}")
        object.__setattr__(self, "n_residuals", counts)
        reasons = tuple(str(v) for v in self.reasons)
        if len(reasons) != 3:
            raise ValidationError(f"reasons must hold 3 strings, got {self.reasons!r}")
        object.__setattr__(self, "reasons", reasons)
        tails = tuple(float(v) for v in self.tail_factors)
        if len(tails) != 3 or not all(math.isfinite(v) and v >= 1.0 for v in tails):
            raise ValidationError(f"tail_factors must be 3 finite factors >= 1, got "
                                  f"{self.tail_factors!r}")
        object.__setattr__(self, "tail_factors", tails)


@dataclass(frozen=True, kw_only=True, slots=True)
class NoiseEstimate:
    """Every node's measurement noise as estimated from a recording.

    nodes : name -> :class:`NodeNoiseEstimate`, in the recording's node order.
    fallback : the sigmas used for components the data do not identify
        (default the paper's, :class:`MeasurementNoise`).
    method : the estimator (:mod:`mmsnap_graph.calibration.noise.estimate`).
    message : a one-line account (what was estimated, what was not and why).
    """

    nodes: Mapping[str, NodeNoiseEstimate]
    fallback: MeasurementNoise = field(default_factory=MeasurementNoise)
    method: str = ""
    message: str = ""

    def __post_init__(self) -> None:
        if not self.nodes:
            raise ValidationError("a NoiseEstimate needs at least one node")
        for name, est in self.nodes.items():
            if not isinstance(est, NodeNoiseEstimate):
                raise ValidationError(f"nodes[{name!r}] must be a NodeNoiseEstimate, got {est!r}")
        object.__setattr__(self, "nodes", dict(self.nodes))

    @property
    def per_node(self) -> dict[str, MeasurementNoise]:
        """name -> the :class:`MeasurementNoise` to use for that node."""
        return {n: e.noise for n, e in self.nodes.items()}

    @property
    def any_identified(self) -> bool:
        """True when some component of some node was estimated from the data."""
        return any(any(e.identified) for e in self.nodes.values())

    def pooled(self) -> MeasurementNoise:
        """One network-wide :class:`MeasurementNoise`: per component, the
        root mean square of the nodes' sigmas weighted by their residual
        counts (equal weights where no node identified the component), for
        estimators that take a single noise."""
        sig = np.array([e.noise.sigmas for e in self.nodes.values()])
        w = np.array([e.n_residuals for e in self.nodes.values()], dtype=float)
        w = np.where(w.sum(axis=0) > 0, w, 1.0)
        pooled = np.sqrt(np.sum(w * sig**2, axis=0) / np.sum(w, axis=0))
        return MeasurementNoise(range_m=pooled[0], omega_rad=pooled[1], doppler_mps=pooled[2])

    def summary(self) -> str:
        """One line per node: each sigma, and whether it was estimated or is
        the fallback (with the reason)."""
        units = ("m", "rad", "m/s")
        lines = []
        for name, e in self.nodes.items():
            parts = []
            for i, comp in enumerate(("range", "omega", "doppler")):
                value = f"{comp} {e.noise.sigmas[i]:.4g} {units[i]}"
                if e.identified[i]:
                    parts.append(f"{value} estimated ({e.n_residuals[i]} residuals)")
                else:
                    parts.append(f"{value} NOT identified, fallback used ({e.reasons[i]})")
            lines.append(f"{name} [{e.method}]: " + "; ".join(parts))
        return "\n".join(lines)


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
