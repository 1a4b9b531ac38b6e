"""An extended human body seen from above, for limb micro-Doppler
(docs/SIMULATOR.md).

The torso follows the given states (what truth tracks); arms and legs swing
about the shoulders and hips along the walking direction with the gait phase

.. math:: \\psi(t) = \\psi_0 + 2\\pi \\int_0^t |v(\\tau)| \\, d\\tau / L_{stride}

so a standing target's limbs stay still. A limb point at distance ``a`` from
its pivot, with swing angle ``alpha(t) = A sin(psi + phase)``, sits at
``pivot + a sin(alpha) h`` (``h`` the unit heading, the vertical part does not
project onto the ground plane) and moves at
``v_torso + a cos(alpha) alpha'(t) h`` plus the rotation of the body about
the torso centre when the walker turns (rate from the heading's change). Feet reach two to three times the
walking speed, as measured on walking humans.

Scatterers, in a fixed order (index ``m``):

- torso: ``n_torso`` points on an ellipse (half-width across the heading,
  half-depth along it), symmetric, so their mean is the torso centre;
- two arms (left, right), ``n_per_limb`` points each, in anti-phase with the
  leg of the same side;
- two legs (left, right), ``n_per_limb`` points each, in anti-phase.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import ValidationError
from .._validation import as_float_array, check_count, check_finite

__all__ = ["PART_NAMES", "TORSO", "ARM", "LEG", "HumanBody", "BodyScatterers",
           "body_scatterers"]

TORSO, ARM, LEG = 0, 1, 2
#: Names of the part labels ``TORSO, ARM, LEG``.
PART_NAMES = ("torso", "arm", "leg")


@dataclass(frozen=True, kw_only=True, slots=True)
class HumanBody:
    """Dimensions and reflectivities of a walking adult (SI units).

    Amplitudes are the amplitude scale of each scatterer (square root of its
    share of ``torso_rcs_m2``); the torso's points' squares sum to
    ``torso_amplitude**2 = 1``, so a whole arm has an RCS of
    ``arm_amplitude**2 * torso_rcs_m2`` (0.045 m^2) and a leg
    ``leg_amplitude**2 * torso_rcs_m2`` (0.08 m^2), 8 to 10 dB below the
    torso (0.5 m^2 at 77 GHz).
    """

    torso_half_width_m: float = 0.18
    torso_half_depth_m: float = 0.11
    shoulder_offset_m: float = 0.20
    hip_offset_m: float = 0.10
    arm_length_m: float = 0.65
    leg_length_m: float = 0.90
    arm_swing_rad: float = 0.35
    leg_swing_rad: float = 0.45
    stride_length_m: float = 1.40
    n_torso: int = 6
    n_per_limb: int = 3
    torso_amplitude: float = 1.0
    arm_amplitude: float = 0.3
    leg_amplitude: float = 0.4
    torso_rcs_m2: float = 0.5

    def __post_init__(self) -> None:
        for name in ("torso_half_width_m", "torso_half_depth_m", "shoulder_offset_m",
                     "hip_offset_m", "arm_length_m", "leg_length_m", "stride_length_m",
                     "torso_amplitude", "torso_rcs_m2"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValidationError(f"{name}={v!r} must be finite and > 0")
        for name in ("arm_swing_rad", "leg_swing_rad", "arm_amplitude", "leg_amplitude"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise ValidationError(f"{name}={v!r} must be finite and >= 0")
        for name in ("n_torso", "n_per_limb"):
            v = getattr(self, name)
            check_count(v, name)
        if self.n_torso % 2:
            raise ValidationError(f"n_torso={self.n_torso!r} must be even (a symmetric torso)")

    @property
    def n_scatterers(self) -> int:
        return int(self.n_torso + 4 * self.n_per_limb)

    @property
    def part(self) -> NDArray:
        """(M,) int part label of each scatterer (``TORSO``, ``ARM``, ``LEG``)."""
        n = self.n_per_limb
        return np.concatenate([np.full(self.n_torso, TORSO), np.full(2 * n, ARM),
                               np.full(2 * n, LEG)]).astype(np.int64)

    @property
    def amplitudes(self) -> NDArray:
        """(M,) amplitude of each scatterer."""
        n = self.n_per_limb
        return np.concatenate([
            np.full(self.n_torso, self.torso_amplitude / np.sqrt(self.n_torso)),
            np.full(2 * n, self.arm_amplitude / np.sqrt(n)),
            np.full(2 * n, self.leg_amplitude / np.sqrt(n)),
        ])

    @property
    def rcs_m2(self) -> NDArray:
        """(M,) radar cross-section of each scatterer, ``amplitude**2 * torso_rcs_m2``."""
        return self.amplitudes ** 2 * self.torso_rcs_m2


@dataclass(frozen=True, kw_only=True, slots=True)
class BodyScatterers:
    """Point scatterers of a body over frames, global frame.

    positions_m, velocities_mps : (F, M, 2); amplitudes, rcs_m2 : (M,);
    part : (M,) int labels (``TORSO``, ``ARM``, ``LEG``; names in
    :data:`PART_NAMES`); gait_phase_rad : (F,).
    """

    positions_m: NDArray
    velocities_mps: NDArray
    amplitudes: NDArray
    rcs_m2: NDArray
    part: NDArray
    gait_phase_rad: NDArray


def body_scatterers(states: ArrayLike, frame_period_s: float, *,
                    body: HumanBody | None = None, phase0_rad: float = 0.0,
                    rng: np.random.Generator | None = None) -> BodyScatterers:
    """Scatterers of a walking human whose torso follows ``states``.

    states : (F, 4) torso ``(x_m, y_m, vx_mps, vy_mps)`` at frames spaced by
    ``frame_period_s``, global frame.
    body : dimensions (default :class:`HumanBody`); ``phase0_rad`` is the gait
    phase at frame 0, random when ``rng`` is given.
    Returns :class:`BodyScatterers` with ``M = body.n_scatterers``.
    """
    body = HumanBody() if body is None else body
    s = check_finite(as_float_array(states, "states"), "states")
    if s.ndim != 2 or s.shape[1] != 4:
        raise ValidationError(f"states must have shape (F, 4), got {s.shape}")
    if not (np.isfinite(frame_period_s) and frame_period_s > 0):
        raise ValidationError(f"frame_period_s={frame_period_s!r} must be finite and > 0")
    if rng is not None:
        phase0_rad = float(rng.uniform(0, 2 * np.pi))
    n_f = s.shape[0]
    speed = np.hypot(s[:, 2], s[:, 3])
    # Heading: the walking direction; hold the last one while standing.
    heading = np.zeros(n_f)
    last = 0.0
    for k in range(n_f):
        if speed[k] > 0.05:
            last = np.arctan2(s[k, 3], s[k, 2])
        heading[k] = last
    if n_f and speed[0] <= 0.05:
        moving = np.flatnonzero(speed > 0.05)
        if moving.size:
            heading[: moving[0]] = np.arctan2(s[moving[0], 3], s[moving[0], 2])
    # Turning rate: the body rotates about the torso centre, which moves the
    # off-centre points. A reversal (straight walk's end, > pi/2 in one frame)
    # is an about-turn within a frame and contributes no rate.
    unwrapped = np.unwrap(heading)
    jump = np.abs(np.diff(unwrapped)) > np.pi / 2
    steps = np.where(jump, 0.0, np.diff(unwrapped))
    smooth = np.concatenate([[0.0], np.cumsum(steps)])
    turn_rate = (np.gradient(smooth, frame_period_s) if n_f > 1 else np.zeros(n_f))
    h = np.stack([np.cos(heading), np.sin(heading)], axis=-1)          # (F, 2) forward
    lat = np.stack([-np.sin(heading), np.cos(heading)], axis=-1)       # (F, 2) left
    dist = np.concatenate([[0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) * frame_period_s)])
    omega_gait = 2 * np.pi / body.stride_length_m
    psi = phase0_rad + omega_gait * dist                                # (F,)
    dpsi = omega_gait * speed                                           # (F,) rad/s

    pos, vel = [], []
    # Torso: an ellipse of points, rigidly translating with the torso.
    ang = 2 * np.pi * (np.arange(body.n_torso) + 0.5) / body.n_torso
    across = body.torso_half_width_m * np.cos(ang)
    along = body.torso_half_depth_m * np.sin(ang)
    pos.append(s[:, None, :2] + across[None, :, None] * lat[:, None, :]
               + along[None, :, None] * h[:, None, :])
    # d/dt (c lat + e h) = turn_rate (-c h + e lat) for body-fixed offsets c, e.
    vel.append(s[:, None, 2:] + turn_rate[:, None, None] * (
        -across[None, :, None] * h[:, None, :] + along[None, :, None] * lat[:, None, :]))
    frac = (np.arange(body.n_per_limb) + 1.0) / body.n_per_limb       # along the limb

    def limb(offset_m: float, length_m: float, swing_rad: float, phase: float):
        alpha = swing_rad * np.sin(psi + phase)                         # (F,)
        dalpha = swing_rad * np.cos(psi + phase) * dpsi
        a = frac * length_m                                             # (n,)
        p = (s[:, None, :2] + offset_m * lat[:, None, :]
             + (a[None, :] * np.sin(alpha)[:, None])[..., None] * h[:, None, :])
        fwd = a[None, :] * np.sin(alpha)[:, None]                       # (F, n)
        v = (s[:, None, 2:]
             + (a[None, :] * (np.cos(alpha) * dalpha)[:, None])[..., None] * h[:, None, :]
             + turn_rate[:, None, None] * (-offset_m * h[:, None, :]
                                           + fwd[..., None] * lat[:, None, :]))
        return p, v

    # Left leg phase 0, right leg pi; each arm swings opposite to its leg.
    for side, phase in ((+1, np.pi), (-1, 0.0)):                        # arms: left, right
        p, v = limb(side * body.shoulder_offset_m, body.arm_length_m, body.arm_swing_rad, phase)
        pos.append(p)
        vel.append(v)
    for side, phase in ((+1, 0.0), (-1, np.pi)):                        # legs: left, right
        p, v = limb(side * body.hip_offset_m, body.leg_length_m, body.leg_swing_rad, phase)
        pos.append(p)
        vel.append(v)
    return BodyScatterers(positions_m=np.concatenate(pos, axis=1),
                          velocities_mps=np.concatenate(vel, axis=1),
                          amplitudes=body.amplitudes, rcs_m2=body.rcs_m2, part=body.part,
                          gait_phase_rad=psi)
