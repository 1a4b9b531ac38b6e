"""Centroids in a node's local frame without the bias of the angle's noise.

:func:`factors.models.detection_to_local` maps a detection to ``(u, v) = (R
s, R sqrt(1 - s^2))``, ``s = Omega / pi``. With noise on ``Omega`` (standard
deviation ``sigma_s = sigma_Omega / pi`` on ``s``) ``u`` is unbiased, but
``sqrt(1 - s^2)`` is concave, so the boresight coordinate comes out short on
average:

.. math::

    E[\\sqrt{1 - s^2}] = c_0 - \\frac{\\sigma_s^2}{2 c_0^3} + O(\\sigma_s^4),
    \\quad c_0 = \\sqrt{1 - s_0^2}.

At the simulator's centroid noise it is millimetres: small against one
centroid's noise, but common to every frame of a recording, so a pose solved
from hundreds of such points carries it whole, enough to push the pose
graph's NEES out of its band (docs/CALIBRATION.md, "Network: all poses from
the matched points").
:func:`debias_centroid_tracks` adds the second-order term back, ``v = R (c +
sigma_s^2 / (2 c^3))``, with ``c`` floored at :data:`MIN_COS` and
``sigma_Omega`` estimated from each node's own centroid sequence
(:func:`~mmsnap_graph.calibration.noise.estimate.temporal_noise`: no poses
needed). The range's noise does not bias ``(u, v)`` (it multiplies both
coordinates and is independent of the angle's).
"""

from __future__ import annotations

import dataclasses

import numpy as np
from numpy.typing import NDArray

from ...data.recording import Detections
from .matching import LocalTracks
from ..noise.estimate import temporal_noise

__all__ = ["MIN_COS", "boresight_bias_correction", "debias_centroid_tracks"]

#: Floor of ``cos(theta)`` in the correction: near end-fire the expansion
#: fails (the term grows as ``1 / c^3``); 0.3 is 72.5 degrees off boresight.
MIN_COS = 0.3


def boresight_bias_correction(range_m: NDArray, sin_theta: NDArray,
                              omega_sigma_rad: float) -> NDArray:
    """``R sigma_s^2 / (2 c^3)`` (m): what to add to the boresight coordinate
    ``v`` of :func:`~factors.models.detection_to_local` (module doc)."""
    c = np.maximum(np.sqrt(np.clip(1.0 - sin_theta**2, 0.0, 1.0)), MIN_COS)
    sigma_s = float(omega_sigma_rad) / np.pi
    return np.asarray(range_m) * sigma_s**2 / (2.0 * c**3)


def debias_centroid_tracks(tracks: LocalTracks) -> tuple[LocalTracks, float]:
    """``tracks`` with the boresight bias of the angle's noise removed
    (module doc), and the spatial-frequency sigma used (rad; NaN, and the
    tracks unchanged, when they are not centroids, carry covariances, or have
    no run of consecutive frames to estimate it from).

    The detections are recovered exactly from the local points (``R = |p|``,
    ``s = u / R``): :func:`~factors.models.detection_to_local` is one to one
    on ``v >= 0``.
    """
    if tracks.source != "centroids" or tracks.covariances is not None or tracks.frame.size == 0:
        return tracks, float("nan")
    p = tracks.points_m
    rng = np.hypot(p[:, 0], p[:, 1])
    s = np.divide(p[:, 0], rng, out=np.zeros_like(rng), where=rng > 0)
    det = Detections(frame=tracks.frame, range_m=rng, omega_rad=np.pi * s,
                     doppler_mps=np.zeros_like(rng),
                     target_id=np.where(tracks.track_id >= 0, tracks.track_id, -1))
    sigmas, counts = temporal_noise(det)
    if counts[1] == 0 or not np.isfinite(sigmas[1]):
        return tracks, float("nan")
    pts = p.copy()
    pts[:, 1] += boresight_bias_correction(rng, s, float(sigmas[1]))
    return dataclasses.replace(tracks, points_m=pts), float(sigmas[1])
