"""A radar's angle bias: what a calibrated heading means against a tape.

A TI radar whose receive channels' phases are not compensated (the
out-of-box demo's ``compRangeBiasAndRxChanPhase`` left at its identity
values, as in the shared recordings' configuration) measures every angle of
arrival off by a few degrees, the same for every target: ``theta_measured =
theta + b``. The self-calibration cannot tell that bias from the heading: a
radar turned by ``-b`` measures the same ranges, angles and Dopplers. The
calibrated heading is the radar's *effective* heading, physical heading plus
bias, and it is the right one for fusion: with it the radar's detections
land where the other radars see the target (so the fused covariance leaves
it out). Against a physical mounting (a tape, a drawing) it is an error:

- node ``n``'s heading is off by ``b_ref - b_n`` (its own bias and the
  reference's, whose frame is the reference frame);
- every node's position is turned about the reference by ``b_ref``: off by
  ``b_ref |p_n|`` across the line from the reference.

The biases are not estimated: range, angle and Doppler carry no trace of
them (a bias of the spatial frequency, ``omega + delta``, is a rotation up to
``1 - cos theta`` of the walk's angles, a few hundredths of a radian over a
+-30 deg walk against a centroid sigma of ~0.2 rad). They are a *considered*
parameter of :func:`mounting_covariance`, each radar's independent with
rms :data:`ANGLE_BIAS_RMS_RAD`; on the two shared real recordings the
calibrated S2 heading is 3.4-3.8 deg from the tape (docs/CALIBRATION.md,
"A node's heading against a tape").
"""

from __future__ import annotations

from typing import Mapping

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import ValidationError

__all__ = ["ANGLE_BIAS_RMS_RAD", "mounting_covariance", "mounting_covariances"]

#: Root mean square of one radar's uncompensated angle bias (rad): 3 deg,
#: the order of the residual boresight bias an IWR1843 shows even after
#: TI's phase calibration (module doc).
ANGLE_BIAS_RMS_RAD = float(np.deg2rad(3.0))


def mounting_covariance(pose: ArrayLike, covariance: ArrayLike, *,
                        angle_bias_rms_rad: float = ANGLE_BIAS_RMS_RAD) -> NDArray:
    """(3, 3) the covariance of a calibrated non-reference node pose
    ``(x_m, y_m, phi_rad)`` (in the reference's frame) against its physical
    mounting: ``covariance`` (the calibration's, Pose2 body tangent
    ``(dx_b, dy_b, dphi)``) plus the two radars' angle biases (module doc),
    in the same tangent. The reference node's own pose has no error (it is
    the frame): do not call this for it."""
    p = np.asarray(pose, dtype=float)
    c = np.asarray(covariance, dtype=float)
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        raise ValidationError(f"pose must be 3 finite numbers (x_m, y_m, phi_rad), got {pose!r}")
    if c.shape != (3, 3):
        raise ValidationError(f"covariance must be (3, 3), got shape {c.shape}")
    s = float(angle_bias_rms_rad)
    if not (np.isfinite(s) and s >= 0):
        raise ValidationError(f"angle_bias_rms_rad={angle_bias_rms_rad!r} must be >= 0")
    # Reference frame: the reference's bias turns the node about the origin
    # (d p = b_ref (-y, x), d phi = b_ref), the node's own turns its heading.
    turn = np.array([-p[1], p[0], 1.0])
    ref_frame = s**2 * (np.outer(turn, turn) + np.diag([0.0, 0.0, 1.0]))
    cos, sin = np.cos(p[2]), np.sin(p[2])
    to_body = np.array([[cos, sin, 0.0], [-sin, cos, 0.0], [0.0, 0.0, 1.0]])
    return c + to_body @ ref_frame @ to_body.T


def mounting_covariances(poses: Mapping[str, ArrayLike], covariances: Mapping[str, ArrayLike],
                         reference: str, *,
                         angle_bias_rms_rad: float = ANGLE_BIAS_RMS_RAD) -> dict[str, NDArray]:
    """:func:`mounting_covariance` of every node in ``covariances`` but the
    ``reference`` (whose entry stays as given)."""
    return {n: (np.asarray(c, dtype=float) if n == reference
                else mounting_covariance(poses[n], c, angle_bias_rms_rad=angle_bias_rms_rad))
            for n, c in covariances.items()}
