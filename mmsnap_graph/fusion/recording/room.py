"""Room-frame checks of fused rows: room bounds and one target per body.

Two checks need the nodes' poses, so they run on the fused rows (the
reference frame), after the robust gate and the motion check:

- **room bounds** (:class:`RoomBounds`): a successful row whose position lies
  outside the room box (``x_min..x_max, y_min..y_max`` in the reference
  frame) is flagged :attr:`~mmsnap_graph.data.results.Status.OUTSIDE_BOUNDS`.
  A reflection via a wall is seen behind the wall: outside the room.
- **in front of the radars** (optional, ``in_front``): radars hung on the
  room's walls look into the room, so a row behind any radar (negative
  boresight coordinate in its frame) is outside it and flagged the same way.
  Not for a radar in the middle of a room, with people behind it.
- **static bounds** (optional, TI's ``staticBoundaryBox``): a row slower than
  :data:`STILL_MPS` outside this box is flagged the same way (a target may
  stand still only inside it).
- **learned walls** (on by default, ``walls``; without ``bounds``, whose box
  are the walls): a row beyond a wall that the nodes' multipath images
  taught (:mod:`.walls`) is flagged the same way: a radar cannot see a
  person through a wall.
- **one target per body**: two successful rows of a frame whose distance is
  consistent with one body are one person seen twice (a split body, or a
  node's centroid not associated with the other node's): with ``d`` their
  distance, ``C_a``, ``C_b`` their position covariances and a body of
  ``body_m`` across (a Gaussian extent of sigma ``body_m / 2`` for each
  node's view of it), ``d' (C_a + C_b + (body_m / 2)^2 I)^-1 d`` within the
  99% chi-square(2) quantile, or ``d < body_m`` (about 0.75 m for rows
  known to a few centimetres). Each radar sees the near side of a body, so
  two radars facing each other see one walker up to a torso's depth apart,
  and a node's own centroid is often a few decimetres off across range. The
  row seen by fewer nodes (else with the larger cost) is flagged
  :attr:`~mmsnap_graph.data.results.Status.DUPLICATE`. Two people closer
  than that are one target for this check.

:func:`screen_room` applies them to a :class:`FusedSequence` and says what it
flagged.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ...data.body import BODY_WIDTH_M
from ...data.results import FusedSequence, Status
from ...errors import ValidationError
from .walls import beyond_learned_walls, learn_walls

__all__ = ["RoomBounds", "RoomReport", "screen_room", "learn_room_walls", "DEFAULT_BODY_M", "STILL_MPS"]

#: A body's width (m): fused people closer than this in one frame are one
#: (:data:`~mmsnap_graph.data.body.BODY_WIDTH_M` says why it is not a merge radius).
DEFAULT_BODY_M = BODY_WIDTH_M
#: Two rows are one body within this chi-square(2) quantile (99%).
BODY_CHI2 = 9.21
#: A fused target slower than this (m/s) stands still (``static_bounds``).
STILL_MPS = 0.2


@dataclass(frozen=True, kw_only=True, slots=True)
class RoomBounds:
    """The room box in the reference frame (metres)."""

    x_min: float
    x_max: float
    y_min: float
    y_max: float

    def __post_init__(self) -> None:
        for name in ("x_min", "x_max", "y_min", "y_max"):
            value = getattr(self, name)
            if isinstance(value, bool) or not np.isfinite(float(value)):
                raise ValidationError(f"room bounds: {name}={value!r} must be a finite number (m)")
            object.__setattr__(self, name, float(value))
        if not (self.x_min < self.x_max and self.y_min < self.y_max):
            raise ValidationError(f"room bounds ({self.x_min}, {self.x_max}, {self.y_min}, "
                                  f"{self.y_max}) must be x_min < x_max, y_min < y_max")

    def contains(self, xy: NDArray) -> NDArray:
        """(K,) True for the positions ``xy`` (K, 2) inside the box (edges included)."""
        xy = np.asarray(xy, dtype=float)
        return ((xy[:, 0] >= self.x_min) & (xy[:, 0] <= self.x_max)
                & (xy[:, 1] >= self.y_min) & (xy[:, 1] <= self.y_max))

    def text(self) -> str:
        return (f"x {self.x_min:g}..{self.x_max:g} m, y {self.y_min:g}..{self.y_max:g} m")


@dataclass(frozen=True, slots=True)
class RoomReport:
    """Rows flagged by :func:`screen_room`: outside the bounds (all
    ``OUTSIDE_BOUNDS`` rows), of which ``beyond_wall`` behind a learned wall,
    duplicates; ``walls``: the learned walls in words."""

    outside: int = 0
    duplicate: int = 0
    beyond_wall: int = 0
    walls: tuple = ()

    def __add__(self, other: "RoomReport") -> "RoomReport":
        walls = self.walls + tuple(w for w in other.walls if w not in self.walls)
        return RoomReport(self.outside + other.outside, self.duplicate + other.duplicate,
                          self.beyond_wall + other.beyond_wall, walls)


def _duplicates(fused: FusedSequence, ok: NDArray, body_m: float) -> NDArray:
    """(K,) True for the rows that repeat a better-supported row of their frame."""
    dup = np.zeros(len(fused), dtype=bool)
    rows = np.flatnonzero(ok)
    if rows.size < 2:
        return dup
    nodes = np.asarray(fused.observed)[rows].sum(axis=1) - np.asarray(fused.rejected)[rows].sum(
        axis=1)
    cost = np.nan_to_num(np.asarray(fused.final_cost, dtype=float)[rows], nan=np.inf)
    # Best first: more nodes, then lower cost; a row is a duplicate when a
    # better row of its frame that is kept lies within body_m.
    order = np.lexsort((cost, -nodes))
    frame = np.asarray(fused.frame)[rows]
    xy = np.asarray(fused.state, dtype=float)[rows, :2]
    cov = np.nan_to_num(np.asarray(fused.covariance, dtype=float)[rows, :2, :2], nan=0.0)
    extent = (body_m / 2.0) ** 2 * np.eye(2)

    def same_body(a: int, b: int) -> bool:
        d = xy[a] - xy[b]
        if np.hypot(*d) < body_m:
            return True
        return float(d @ np.linalg.solve(cov[a] + cov[b] + extent, d)) <= BODY_CHI2

    kept: dict[int, list[int]] = {}
    for k in order:
        here = kept.setdefault(int(frame[k]), [])
        if any(same_body(k, j) for j in here):
            dup[rows[k]] = True
        else:
            here.append(k)
    return dup


def _behind(fused: FusedSequence) -> tuple[NDArray, NDArray]:
    """(K,) True for the rows behind a node (its boresight coordinate < 0),
    and (K,) the index of the first such node."""
    xy = np.asarray(fused.state, dtype=float)[:, :2]
    poses = np.asarray(fused.node_poses, dtype=float)
    d = xy[:, None, :] - poses[None, :, :2]
    ahead = -np.sin(poses[:, 2]) * d[..., 0] + np.cos(poses[:, 2]) * d[..., 1]
    back = ahead < 0
    return back.any(axis=1), np.argmax(back, axis=1)


def _seen(fused: FusedSequence, success: NDArray) -> NDArray:
    """(K, N) the nodes that saw each row: a row the gate or the motion check
    flagged is still what a node saw (an image, often), with every node it
    was grouped with."""
    observed = np.asarray(fused.observed, dtype=bool)
    rejected = np.zeros_like(observed) if fused.rejected is None else np.asarray(
        fused.rejected, dtype=bool)
    return np.where(success[:, None], observed & ~rejected, observed)


def learn_room_walls(fused: FusedSequence, success: NDArray | None = None,
                     body_m: float = DEFAULT_BODY_M) -> list:
    """The walls (:class:`~.walls.LearnedWall`) the multipath images of the
    rows of ``fused`` teach (:func:`~.walls.learn_walls`); ``success`` (K,)
    the rows taken as people (default ``fused.success``)."""
    success = np.asarray(fused.success if success is None else success, dtype=bool)
    if len(fused) == 0:
        return []
    status = np.asarray(fused.status)
    state = np.asarray(fused.state, dtype=float)
    # A row the gate or the motion check flagged may teach a wall.
    image_ok = np.all(np.isfinite(state), axis=1) & np.isin(
        status, (Status.OK, Status.RESIDUAL_TEST_FAILED, Status.MOTION_INCONSISTENT))
    poses = np.asarray(fused.node_poses, dtype=float)
    return learn_walls(np.asarray(fused.frame), state, np.asarray(fused.covariance), success,
                       _seen(fused, success), poses, body_m=body_m,
                       image_ok=image_ok | success)


def _learned_walls(fused: FusedSequence, success: NDArray, body_m: float, learned=None):
    """The learned-walls check (:mod:`.walls`): flags, wall index, walls
    (``learned``: the walls to apply; None: learned from ``fused``)."""
    walls = learn_room_walls(fused, success, body_m) if learned is None else list(learned)
    poses = np.asarray(fused.node_poses, dtype=float)
    flag, which = beyond_learned_walls(np.asarray(fused.state, dtype=float), success,
                                       _seen(fused, success), poses, walls)
    return flag, which, walls


def screen_room(fused: FusedSequence, *, bounds: RoomBounds | None = None,
                static_bounds: RoomBounds | None = None, in_front: bool = False,
                walls: bool = True, learned: list | None = None,
                body_m: float | None = DEFAULT_BODY_M) -> tuple[FusedSequence, RoomReport]:
    """Flag the successful rows outside ``bounds`` (None: no bounds), the
    still rows outside ``static_bounds``, the rows behind a node
    (``in_front``), the rows beyond a wall learned from the multipath images
    (``walls``; ``learned``: those walls instead of the ones ``fused`` teaches)
    and the duplicates of one body (``body_m``; None: off).
    Returns the rows with their ``success``, ``status`` and ``message``
    updated, and the counts."""
    if body_m is not None and not (np.isfinite(body_m) and body_m > 0):
        raise ValidationError(f"body_m={body_m!r} must be finite and > 0 (m)")
    if len(fused) == 0:
        return fused, RoomReport()
    success = np.asarray(fused.success, dtype=bool).copy()
    status = np.asarray(fused.status).copy()
    message = np.asarray(fused.message, dtype=object).copy()
    outside = np.zeros(len(fused), dtype=bool)
    if bounds is not None:
        outside = success & ~bounds.contains(np.asarray(fused.state)[:, :2])
        status[outside] = Status.OUTSIDE_BOUNDS
        message[outside] = f"outside the room bounds ({bounds.text()})"
        success &= ~outside
    if in_front:
        back, node = _behind(fused)
        back &= success
        status[back] = Status.OUTSIDE_BOUNDS
        for k in np.flatnonzero(back):
            message[k] = f"behind node {fused.node_names[node[k]]} (outside the room)"
        success &= ~back
        outside |= back
    if static_bounds is not None:
        state = np.asarray(fused.state, dtype=float)
        still = success & (np.hypot(state[:, 2], state[:, 3]) < STILL_MPS) \
            & ~static_bounds.contains(state[:, :2])
        status[still] = Status.OUTSIDE_BOUNDS
        message[still] = (f"still (< {STILL_MPS:g} m/s) outside the static bounds "
                          f"({static_bounds.text()})")
        success &= ~still
        outside |= still
    beyond, given, learned = np.zeros(len(fused), dtype=bool), learned, []
    if walls and bounds is None:
        beyond, which, learned = _learned_walls(fused, success, DEFAULT_BODY_M, given)
        status[beyond] = Status.OUTSIDE_BOUNDS
        for k in np.flatnonzero(beyond):
            message[k] = ("beyond a wall learned from multipath images ("
                          f"{learned[which[k]].text(fused.node_names)}): outside the room")
        success &= ~beyond
        outside |= beyond
    wall_text = tuple(w.text(fused.node_names) for w in learned)
    dup = np.zeros(len(fused), dtype=bool)
    if body_m is not None:
        dup = _duplicates(fused, success, float(body_m))
        status[dup] = Status.DUPLICATE
        message[dup] = (f"one body ({body_m:g} m across) with a better-supported target of its "
                        "frame")
        success &= ~dup
    if not (outside.any() or dup.any()):
        return fused, RoomReport(walls=wall_text)
    out = dataclasses.replace(fused, success=success, status=status.astype(
        np.asarray(fused.status).dtype), message=message)
    return out, RoomReport(int(outside.sum()), int(dup.sum()), int(beyond.sum()), wall_text)
