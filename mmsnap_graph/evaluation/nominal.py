"""Calibrated poses against the nominal poses the user gave: the policy
``mmsnap calibrate`` and ``mmsnap monitor`` report by.

A nominal pose is what the user said a node's pose is: the room pose of a
room-frame log (``mmsnap import --room-pose``) or a surveyed pose
(``--pose``). The import stores them in the recording's metadata
(:func:`nominal_metadata`, docs/FORMAT.md); :func:`nominal_poses` reads them
back. A calibration finds each node's pose from the data; one far from its
nominal pose (more than :data:`NOMINAL_DISTANCE_M` or
:data:`NOMINAL_HEADING_RAD`) is a mistake of the one or the other, and
:func:`pose_departures` names the likely cause:

- ``"boresight"``: the headings differ by about 90 deg: the boresight's
  direction given where the array axis's is meant (the heading is the
  direction of the antenna array axis, the boresight heading + 90 deg);
- ``"reversed"``: about 180 deg: the radar faces the other way;
- ``"radians"``: the nominal heading, a few degrees, is what the calibrated
  heading is in radians (radians typed where degrees are asked);
- ``"room_frame"``: the node was calibrated at the reference's own place
  and heading: its points were already in a frame common to both (a room
  frame without ``--room-pose`` at import);
- ``"unknown"``.

:func:`coincident_nodes` needs no nominal pose: two nodes calibrated within
:data:`COINCIDENT_DISTANCE_M` and :data:`COINCIDENT_HEADING_RAD` of each
other are two radars at one place looking the same way, which is what points
already in one room frame calibrate to. Facts only; the command line words them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal, Mapping

import numpy as np
from numpy.typing import ArrayLike, NDArray

from factors.models import global_to_local, wrap_angle
from ..errors import ValidationError

__all__ = ["NOMINAL_DISTANCE_M", "NOMINAL_HEADING_RAD", "COINCIDENT_DISTANCE_M",
           "COINCIDENT_HEADING_RAD", "NominalPose", "PoseDeparture", "CoincidentNodes",
           "nominal_metadata", "nominal_poses", "pose_departures", "coincident_nodes"]

#: A calibrated pose this far from its nominal pose is reported.
NOMINAL_DISTANCE_M = 1.0
NOMINAL_HEADING_RAD = float(np.deg2rad(45.0))
#: Two nodes calibrated this close (position and heading) are reported.
COINCIDENT_DISTANCE_M = 0.5
COINCIDENT_HEADING_RAD = float(np.deg2rad(20.0))
#: How near a heading difference must lie to 90 or 180 deg to name that cause.
_CAUSE_TOLERANCE_RAD = float(np.deg2rad(20.0))
#: The metadata keys of a node's nominal pose: ``<node>_nominal_<field>``.
_FIELDS = ("x_m", "y_m", "phi_rad")
SOURCES = ("room_pose", "pose")


@dataclass(frozen=True, kw_only=True, slots=True)
class NominalPose:
    """A node pose the user gave: ``pose`` (3,) ``(x_m, y_m, phi_rad)`` in
    the user's frame (a room's), ``source`` the option (``"room_pose"``:
    ``--room-pose``; ``"pose"``: ``--pose``)."""

    pose: NDArray
    source: Literal["room_pose", "pose"]

    def __post_init__(self) -> None:
        pose = np.asarray(self.pose, dtype=float)
        if pose.shape != (3,) or not np.all(np.isfinite(pose)):
            raise ValidationError(f"pose={self.pose!r} must be 3 finite numbers (x_m, y_m, "
                                  "phi_rad)")
        if self.source not in SOURCES:
            raise ValidationError(f"source={self.source!r} must be one of {list(SOURCES)}")
        object.__setattr__(self, "pose", pose)


@dataclass(frozen=True, kw_only=True, slots=True)
class PoseDeparture:
    """A calibrated pose far from the nominal one: ``node``, the distance
    (m) and heading difference (calibrated - nominal, rad, wrapped) in the
    reference's frame, the ``nominal`` pose there (3,), its ``source`` and
    the likely ``cause`` (module docstring)."""

    node: str
    distance_m: float
    heading_error_rad: float
    nominal: NDArray
    source: str
    cause: Literal["boresight", "reversed", "radians", "room_frame", "unknown"]


@dataclass(frozen=True, kw_only=True, slots=True)
class CoincidentNodes:
    """Two nodes calibrated at one place looking the same way: their names,
    distance (m) and heading difference (rad)."""

    node_a: str
    node_b: str
    distance_m: float
    heading_difference_rad: float


def nominal_metadata(node: str, pose: ArrayLike, source: str) -> dict[str, Any]:
    """The metadata keys that store ``node``'s nominal pose (radians)."""
    nominal = NominalPose(pose=pose, source=source)
    out: dict[str, Any] = {f"{node}_nominal_{f}": float(v) for f, v in zip(_FIELDS, nominal.pose)}
    out[f"{node}_nominal_source"] = nominal.source
    return out


def nominal_poses(metadata: Mapping[str, Any], nodes: list[str] | None = None
                  ) -> dict[str, NominalPose]:
    """node -> its nominal pose, from a recording's metadata
    (:func:`nominal_metadata`); nodes without all the keys are left out."""
    names = nodes if nodes is not None else sorted(
        {k[:-len("_nominal_source")] for k in metadata if k.endswith("_nominal_source")})
    out = {}
    for name in names:
        keys = [f"{name}_nominal_{f}" for f in _FIELDS]
        source = metadata.get(f"{name}_nominal_source")
        if source is None or not all(k in metadata for k in keys):
            continue
        try:
            out[name] = NominalPose(pose=[float(metadata[k]) for k in keys], source=str(source))
        except (TypeError, ValueError):
            continue                                   # a damaged entry is no nominal pose
    return out


def _relative(pose: NDArray, reference: NDArray) -> NDArray:
    """``pose`` in the frame of ``reference`` (both in one frame)."""
    xy = global_to_local(pose[None, :2], reference)[0]
    return np.array([xy[0], xy[1], float(wrap_angle(pose[2] - reference[2]))])


def _cause(calibrated: NDArray, nominal: NDArray, given: NDArray) -> str:
    """The likely cause of a departure (module docstring); ``given`` is the
    nominal pose as the user gave it (its own frame)."""
    dh = float(wrap_angle(calibrated[2] - nominal[2]))
    if np.hypot(*calibrated[:2]) < COINCIDENT_DISTANCE_M \
            and abs(float(wrap_angle(calibrated[2]))) < COINCIDENT_HEADING_RAD:
        return "room_frame"
    degrees_typed = float(np.degrees(given[2]))
    if given[2] != 0 and abs(degrees_typed) <= 2 * np.pi \
            and abs(float(wrap_angle(calibrated[2] - (nominal[2] - given[2] + degrees_typed)))) \
            < _CAUSE_TOLERANCE_RAD:
        return "radians"
    if abs(abs(dh) - np.pi / 2) < _CAUSE_TOLERANCE_RAD:
        return "boresight"
    if abs(dh) > np.pi - _CAUSE_TOLERANCE_RAD:
        return "reversed"
    return "unknown"


def pose_departures(poses: Mapping[str, ArrayLike], nominal: Mapping[str, NominalPose], *,
                    reference: str) -> list[PoseDeparture]:
    """The calibrated ``poses`` (node -> (3,), in the ``reference`` node's
    frame) more than :data:`NOMINAL_DISTANCE_M` or :data:`NOMINAL_HEADING_RAD`
    from their ``nominal`` poses (:func:`nominal_poses`, taken to the
    reference's frame), with the likely cause. Only nodes with a nominal
    pose are compared, and only when the reference has one too."""
    if reference not in nominal:
        return []
    ref = nominal[reference].pose
    out = []
    for name, pose in poses.items():
        if name == reference or name not in nominal:
            continue
        calibrated = np.asarray(pose, dtype=float)
        given = nominal[name].pose
        expected = _relative(given, ref)
        distance = float(np.hypot(*(calibrated[:2] - expected[:2])))
        dh = float(wrap_angle(calibrated[2] - expected[2]))
        if distance <= NOMINAL_DISTANCE_M and abs(dh) <= NOMINAL_HEADING_RAD:
            continue
        out.append(PoseDeparture(node=name, distance_m=distance, heading_error_rad=dh,
                                 nominal=expected, source=nominal[name].source,
                                 cause=_cause(calibrated, expected, given)))
    return out


def coincident_nodes(poses: Mapping[str, ArrayLike]) -> list[CoincidentNodes]:
    """Pairs of nodes calibrated within :data:`COINCIDENT_DISTANCE_M` and
    :data:`COINCIDENT_HEADING_RAD` of each other (poses in one frame)."""
    names = list(poses)
    out = []
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            pa, pb = np.asarray(poses[a], dtype=float), np.asarray(poses[b], dtype=float)
            distance = float(np.hypot(*(pa[:2] - pb[:2])))
            dh = float(wrap_angle(pb[2] - pa[2]))
            if distance < COINCIDENT_DISTANCE_M and abs(dh) < COINCIDENT_HEADING_RAD:
                out.append(CoincidentNodes(node_a=a, node_b=b, distance_m=distance,
                                           heading_difference_rad=dh))
    return out
