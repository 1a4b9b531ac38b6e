"""Which centroids of different nodes are the same target, frame by frame.

With several targets in view each node reports several centroids per frame.
Before one-shot fusion the centroids are grouped across nodes: every
detection is mapped to the global frame with the calibrated node pose
(:func:`factors.models.detection_to_global`, docs/CONVENTIONS.md, the corrected eq. 19), its
2x2 position covariance is propagated from the measurement noise (range and
spatial frequency), and the nodes are taken in order: the first node's
detections seed the groups, each further node's detections are assigned to
the existing groups by a gated minimum-cost assignment
(:func:`scipy.optimize.linear_sum_assignment` on the squared Mahalanobis
distance, pairs beyond the chi-square gate forbidden); a detection left
unassigned starts a group of its own (a target only that node sees, or a false
alarm). A group's position is the information-weighted mean of its members.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import linear_sum_assignment
from scipy.stats import chi2

from factors.models import detection_covariance_global, detection_to_global

from ..errors import ValidationError
from .._validation import as_float_array, check_finite
from ..data.noise import MeasurementNoise
from .problem import check_noise

__all__ = [
    "FrameAssociation",
    "detection_position_covariance",
    "associate_frame",
    "gate_threshold",
]

# Cost of a forbidden pair in the assignment (beyond any gated cost).
_FORBIDDEN = 1e12


def gate_threshold(gate_probability: float) -> float:
    """Squared-Mahalanobis gate of a 2D position: ``chi2.ppf(p, 2)``."""
    p = float(gate_probability)
    if not 0.0 < p < 1.0:
        raise ValidationError(f"gate_probability must be in (0, 1), got {gate_probability!r}")
    return float(chi2.ppf(p, 2))


def detection_position_covariance(
    range_m: ArrayLike, omega_rad: ArrayLike, node_pose: ArrayLike,
    noise: MeasurementNoise = MeasurementNoise(),
) -> NDArray:
    """Covariance of detections mapped to the global frame, (..., 2, 2) m^2.

    First-order propagation of the range and spatial-frequency noise through
    ``p = p_i + R(phi_i) (R s, R sqrt(1 - s^2))``, ``s = Omega / pi``:
    ``d p_local / d R = (s, c)``, ``d p_local / d Omega = (R / pi) (1, -s / c)``
    with ``c = sqrt(1 - s^2)`` floored at ``factors.models.DETECTION_MIN_COS``
    near end-fire (:func:`factors.models.detection_covariance_global`, with the
    sigmas of ``noise``).

    range_m, omega_rad : (...,); node_pose : (..., 3) or (3,);
    noise : the measurement sigmas (range and spatial frequency are used). No validation.
    """
    return detection_covariance_global(range_m, omega_rad, node_pose, noise.range_m, noise.omega_rad)


@dataclass(frozen=True, kw_only=True, slots=True)
class FrameAssociation:
    """Groups of one frame's detections, one group per (putative) target.

    members : (G, N) int, row index of each node's detection in the group
        (into that node's per-frame detections), -1 where the node has none.
    position_m : (G, 2) information-weighted mean of the members' global positions.
    covariance_m2 : (G, 2, 2) its covariance.
    """

    members: NDArray
    position_m: NDArray
    covariance_m2: NDArray

    def __len__(self) -> int:
        return int(self.members.shape[0])


def associate_frame(
    measurements: Sequence[ArrayLike],
    node_poses: ArrayLike,
    noise: MeasurementNoise = MeasurementNoise(),
    *,
    gate_probability: float = 0.999,
) -> FrameAssociation:
    """Group one frame's detections of ``N`` nodes into targets.

    Parameters
    ----------
    measurements : sequence of N arrays (K_n, 3)
        Each node's detections ``(range_m, omega_rad, doppler_mps)`` this frame
        (K_n may be 0).
    node_poses : (N, 3) float
        Calibrated poses in the global frame.
    noise : MeasurementNoise
        Measurement sigmas (default the paper's); they set the position
        covariances and so the gate.
    gate_probability : float
        Probability mass inside the gate (chi-square, 2 dof) of two detections
        of the same target.

    Returns
    -------
    FrameAssociation
        Groups in order of creation: the first node's detections first.
    """
    poses = check_finite(as_float_array(node_poses, "node_poses"), "node_poses")
    if poses.ndim != 2 or poses.shape[1] != 3:
        raise ValidationError(f"node_poses must have shape (N, 3), got {poses.shape}")
    if len(measurements) != poses.shape[0]:
        raise ValidationError(
            f"measurements has {len(measurements)} nodes but node_poses has {poses.shape[0]}"
        )
    check_noise(noise)
    gate = gate_threshold(gate_probability)
    n_nodes = poses.shape[0]

    members: list[list[int]] = []
    info_sum: list[NDArray] = []  # per group: (2, 2) information
    eta_sum: list[NDArray] = []  # per group: (2,) information vector
    for n in range(n_nodes):
        z = check_finite(as_float_array(measurements[n], f"measurements[{n}]"), f"measurements[{n}]")
        if z.ndim != 2 or z.shape[1] != 3:
            raise ValidationError(f"measurements[{n}] must have shape (K, 3), got {z.shape}")
        if z.shape[0] == 0:
            continue
        pos = detection_to_global(z[:, 0], z[:, 1], poses[n])
        cov = detection_position_covariance(z[:, 0], z[:, 1], poses[n], noise)
        assigned = np.full(z.shape[0], -1)
        if members:
            info_g = np.stack(info_sum)
            cov_g = np.linalg.inv(info_g)
            mean_g = np.einsum("gij,gj->gi", cov_g, np.stack(eta_sum))
            d = mean_g[:, None, :] - pos[None, :, :]  # (G, K, 2)
            s = cov_g[:, None] + cov[None, :]  # (G, K, 2, 2)
            m2 = np.einsum("gki,gki->gk", d, np.linalg.solve(s, d[..., None])[..., 0])
            cost = np.where(m2 <= gate, m2, _FORBIDDEN)
            rows, cols = linear_sum_assignment(cost)
            ok = cost[rows, cols] < _FORBIDDEN
            for g, k in zip(rows[ok], cols[ok]):
                # A group takes at most one detection per node.
                assigned[k] = g
        info_k = np.linalg.inv(cov)
        for k in range(z.shape[0]):
            g = assigned[k]
            if g < 0:
                members.append([-1] * n_nodes)
                info_sum.append(np.zeros((2, 2)))
                eta_sum.append(np.zeros(2))
                g = len(members) - 1
            members[g][n] = k
            info_sum[g] = info_sum[g] + info_k[k]
            eta_sum[g] = eta_sum[g] + info_k[k] @ pos[k]
    if not members:
        return FrameAssociation(
            members=np.zeros((0, n_nodes), dtype=np.int64),
            position_m=np.zeros((0, 2)),
            covariance_m2=np.zeros((0, 2, 2)),
        )
    cov_g = np.linalg.inv(np.stack(info_sum))
    cov_g = 0.5 * (cov_g + np.swapaxes(cov_g, -1, -2))
    return FrameAssociation(
        members=np.asarray(members, dtype=np.int64),
        position_m=np.einsum("gij,gj->gi", cov_g, np.stack(eta_sum)),
        covariance_m2=cov_g,
    )
