"""Measurement noise from the residuals of a joint calibration
(:func:`residual_noise`), used by :mod:`.multi_refine` and by
:mod:`~mmsnap_graph.calibration.network` (which exports it too).
"""

from __future__ import annotations

from typing import Mapping

import numpy as np

from factors.models import measurement_model, residual

from ...data.noise import MeasurementNoise
from ...data.recording import Detections
from ...errors import CalibrationError
from .solve import JointCalibration

__all__ = ["residual_noise"]


def residual_noise(result: JointCalibration, detections: Mapping[str, Detections], *,
                   noise: MeasurementNoise, prior_sigmas=(1e3, 1e3, 3.5, 3.5), n_rounds: int = 3,
                   min_redundancy: float = 0.1) -> MeasurementNoise:
    """Noise of each measurement component (range_m, omega_rad, doppler_mps)
    from the inlier residuals of a joint solution *without motion factors*
    (the leverages treat frames apart), corrected for what each
    frame's state absorbs (leverage):

    .. math:: \\hat\\sigma_c^2 = \\sum e_c^2 / \\sum (1 - h_c),

    ``h`` the diagonal of the per-frame hat matrix ``J (J^T W J + P)^{-1}
    J^T W`` (the states at fixed poses), iterated ``n_rounds`` times since
    ``W`` depends on the sigmas. A component whose residuals carry less than
    ``min_redundancy`` of a degree of freedom per measurement is not
    identifiable (e.g. the Doppler of two nodes without motion factors fits
    each frame's velocity exactly) and keeps its value in ``noise``.
    """
    sig = noise.sigmas.copy()
    prior_w = 1.0 / np.asarray(prior_sigmas, dtype=float) ** 2
    rows = []  # (frame index, residual (3,), Jacobian (3, 4)) per inlier detection
    for n, det in detections.items():
        if n not in result.poses:
            continue
        idx = np.clip(np.searchsorted(result.frames, det.frame), 0, result.frames.size - 1)
        hit = result.frames[idx] == det.frame
        keep = hit.copy()
        keep[hit] = ~result.outliers[n][idx[hit]]
        h, jac = measurement_model(result.states[idx[keep]], result.poses[n])
        rows.append((idx[keep], residual(h, det.measurements[keep]), jac))
    if not rows or sum(r[0].size for r in rows) == 0:
        raise CalibrationError("no inlier detection to estimate the noise from")
    f = result.frames.size
    for _ in range(n_rounds):
        info = np.tile(np.diag(prior_w), (f, 1, 1))
        for k, _, jac in rows:
            np.add.at(info, k, np.einsum("kri,r,krj->kij", jac, 1.0 / sig**2, jac))
        cov = np.linalg.inv(info)
        num, den = np.zeros(3), np.zeros(3)
        for k, e, jac in rows:
            lev = np.einsum("kri,kij,krj->kr", jac, cov[k], jac) / sig**2
            num += np.sum(e**2, axis=0)
            den += np.sum(1.0 - lev, axis=0)
        count = sum(r[0].size for r in rows)
        ok = den > min_redundancy * count
        sig = np.where(ok, np.sqrt(num / np.maximum(den, 1e-300)), sig)
    return MeasurementNoise(range_m=sig[0], omega_rad=sig[1], doppler_mps=sig[2])
