"""Radar network geometries: the paper's configurations and any network given
by node poses (docs/SIMULATOR.md).

A node pose is ``(x_m, y_m, phi_rad)`` (docs/CONVENTIONS.md): ``phi`` is the
direction of the array axis and the broadside is ``(-sin phi, cos phi)``.
Node S1 is always at the origin with ``phi = 0`` (broadside +y).

A target is *in view* of a node when its angle of arrival from broadside is
within ``+-fov_rad`` and its range within ``[min_range_m, max_range_m]``.
Targets walk inside a *common area*: an axis-aligned box per configuration,
checked to lie in the common field of view of every node.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.ndimage import distance_transform_cdt

from factors.models import global_to_local

from ..errors import GeometryError, ValidationError
from .._validation import as_float_array, check_finite

__all__ = [
    "DEFAULT_FOV_RAD",
    "DEFAULT_MAX_RANGE_M",
    "DEFAULT_MIN_RANGE_M",
    "CONFIGURATIONS",
    "COMMON_AREAS",
    "Area",
    "network_poses",
    "in_field_of_view",
    "in_common_field_of_view",
    "common_area",
    "random_network",
]

#: Half-angle of each node's field of view (angle of arrival from broadside).
DEFAULT_FOV_RAD = np.pi / 3
#: Largest range at which a walking human is detected; below Table I's
#: unambiguous range of 18.07 m (the paper's humans are within 10 m).
DEFAULT_MAX_RANGE_M = 15.0
#: Closest range at which a target is detected (near-field, antenna leakage).
DEFAULT_MIN_RANGE_M = 0.5


def _pose(x_m: float, y_m: float, phi_rad: float) -> NDArray:
    p = np.array([x_m, y_m, phi_rad], dtype=float)
    p.setflags(write=False)
    return p


#: Node poses of the paper's configurations (helper brief; C is the paper's
#: Sec. IV setup: the radars face each other across 7 m).
CONFIGURATIONS: dict[str, dict[str, NDArray]] = {
    "A": {"S1": _pose(0.0, 0.0, 0.0), "S2": _pose(4.0, 0.0, np.pi / 6)},
    "B": {"S1": _pose(0.0, 0.0, 0.0), "S2": _pose(5.0, 5.0, np.pi / 2)},
    "C": {"S1": _pose(0.0, 0.0, 0.0), "S2": _pose(0.0, 7.0, np.pi)},
}


@dataclass(frozen=True, kw_only=True, slots=True)
class Area:
    """An axis-aligned box ``[x_min_m, x_max_m] x [y_min_m, y_max_m]`` (global frame)."""

    x_min_m: float
    x_max_m: float
    y_min_m: float
    y_max_m: float

    def __post_init__(self) -> None:
        for name in ("x_min_m", "x_max_m", "y_min_m", "y_max_m"):
            v = float(getattr(self, name))
            if not np.isfinite(v):
                raise ValidationError(f"{name}={v!r} must be finite")
            object.__setattr__(self, name, v)
        if not (self.x_max_m > self.x_min_m and self.y_max_m > self.y_min_m):
            raise ValidationError(f"area {self!r} must have x_max_m > x_min_m and "
                                  "y_max_m > y_min_m")

    @property
    def center_m(self) -> NDArray:
        """(2,) centre of the box."""
        return np.array([0.5 * (self.x_min_m + self.x_max_m), 0.5 * (self.y_min_m + self.y_max_m)])

    @property
    def size_m(self) -> NDArray:
        """(2,) width and height."""
        return np.array([self.x_max_m - self.x_min_m, self.y_max_m - self.y_min_m])

    @property
    def corners_m(self) -> NDArray:
        """(4, 2) corners, counter-clockwise from ``(x_min, y_min)``."""
        return np.array([[self.x_min_m, self.y_min_m], [self.x_max_m, self.y_min_m],
                         [self.x_max_m, self.y_max_m], [self.x_min_m, self.y_max_m]])

    def contains(self, points_m: ArrayLike, *, margin_m: float = 0.0) -> NDArray:
        """(...,) bool: points ``(..., 2)`` inside the box shrunk by ``margin_m``."""
        p = np.asarray(points_m, dtype=float)
        return ((p[..., 0] >= self.x_min_m + margin_m) & (p[..., 0] <= self.x_max_m - margin_m)
                & (p[..., 1] >= self.y_min_m + margin_m) & (p[..., 1] <= self.y_max_m - margin_m))


#: Where targets walk in each configuration (the green regions of the
#: paper's Fig. 3); every point is in both nodes' field of view.
COMMON_AREAS: dict[str, Area] = {
    "A": Area(x_min_m=0.5, x_max_m=3.5, y_min_m=3.5, y_max_m=6.5),
    "B": Area(x_min_m=-1.0, x_max_m=2.0, y_min_m=3.0, y_max_m=6.0),
    "C": Area(x_min_m=-1.5, x_max_m=1.5, y_min_m=2.0, y_max_m=5.0),
}


def network_poses(network: str | Mapping[str, ArrayLike]) -> dict[str, NDArray]:
    """Node poses of a named configuration (``"A"``, ``"B"``, ``"C"``) or of a
    mapping ``name -> (3,) pose``, validated; order is kept (first = S1)."""
    if isinstance(network, str):
        key = network.upper()
        if key not in CONFIGURATIONS:
            raise ValidationError(f"configuration={network!r} must be one of "
                                  f"{sorted(CONFIGURATIONS)} or a mapping of node poses")
        return {name: np.array(p) for name, p in CONFIGURATIONS[key].items()}
    poses: dict[str, NDArray] = {}
    for name, pose in dict(network).items():
        p = check_finite(as_float_array(pose, f"pose of {name}"), f"pose of {name}")
        if p.shape != (3,):
            raise ValidationError(f"pose of {name} must have shape (3,), got {p.shape}")
        if not isinstance(name, str) or not name or "/" in name:
            raise ValidationError(f"node name must be a non-empty string without '/', got {name!r}")
        poses[name] = p
    if not poses:
        raise ValidationError("a network needs at least one node pose")
    return poses


def in_field_of_view(points_m: ArrayLike, node_pose: ArrayLike, *,
                     fov_rad: float = DEFAULT_FOV_RAD,
                     max_range_m: float = DEFAULT_MAX_RANGE_M,
                     min_range_m: float = DEFAULT_MIN_RANGE_M) -> NDArray:
    """(...,) bool: global points ``(..., 2)`` seen by a node of pose ``(3,)``.

    In view means local ``y > 0``, ``|theta| <= fov_rad`` with
    ``theta = atan2(x_local, y_local)``, and ``min_range_m <= r <= max_range_m``.
    """
    local = global_to_local(points_m, np.asarray(node_pose, dtype=float))
    r = np.hypot(local[..., 0], local[..., 1])
    theta = np.arctan2(local[..., 0], local[..., 1])
    return (np.abs(theta) <= fov_rad) & (r >= min_range_m) & (r <= max_range_m)


def in_common_field_of_view(points_m: ArrayLike, poses: Mapping[str, ArrayLike], **limits
                            ) -> NDArray:
    """(...,) bool: points ``(..., 2)`` in view of every node (limits as in
    :func:`in_field_of_view`)."""
    p = np.asarray(points_m, dtype=float)
    ok = np.ones(p.shape[:-1], dtype=bool)
    for pose in poses.values():
        ok &= in_field_of_view(p, pose, **limits)
    return ok


def common_area(network: str | Mapping[str, ArrayLike], *,
                fov_rad: float = DEFAULT_FOV_RAD,
                max_range_m: float = DEFAULT_MAX_RANGE_M,
                min_range_m: float = DEFAULT_MIN_RANGE_M,
                margin_m: float = 0.5,
                max_size_m: float = 3.0) -> Area:
    """The box where targets walk.

    For a named configuration: :data:`COMMON_AREAS`. For any other network: the
    largest square (side at most ``max_size_m``) centred on the point of the
    common field of view, at least ``margin_m`` from its edges (sampled on a
    5 cm grid), placed as close as possible to the farthest node. Raises
    :class:`GeometryError` when the nodes have no common field of view.
    """
    if isinstance(network, str) and network.upper() in COMMON_AREAS:
        return COMMON_AREAS[network.upper()]
    poses = network_poses(network)
    limits = dict(fov_rad=fov_rad, max_range_m=max_range_m, min_range_m=min_range_m)
    xy = np.stack([p[:2] for p in poses.values()])
    lo = xy.min(axis=0) - max_range_m
    hi = xy.max(axis=0) + max_range_m
    step = 0.05
    gx = np.arange(lo[0], hi[0] + step, step)
    gy = np.arange(lo[1], hi[1] + step, step)
    grid = np.stack(np.meshgrid(gx, gy, indexing="xy"), axis=-1)
    inside = in_common_field_of_view(grid, poses, **limits)
    if not inside.any():
        raise GeometryError(f"the nodes {list(poses)} have no common field of view "
                            f"(fov_rad={fov_rad}, max_range_m={max_range_m})")
    # Chebyshev distance (in cells) to the nearest outside cell: a square of
    # half-side d around a cell is entirely inside.
    depth = (distance_transform_cdt(np.pad(inside, 1), metric="chessboard")[1:-1, 1:-1]
             - 1) * step
    # The biggest square up to max_size_m, then among the cells deep enough
    # for it the one nearest to its farthest node (targets close to the radars).
    half = min(float(depth.max()) - margin_m, 0.5 * max_size_m)
    if half <= 0.1:
        raise GeometryError(f"the common field of view of {list(poses)} is too small for a "
                            f"walking area with margin_m={margin_m}")
    ok = depth >= half + margin_m - 1e-9
    far = np.max(np.linalg.norm(grid[..., None, :] - xy, axis=-1), axis=-1)
    iy, ix = np.unravel_index(np.argmin(np.where(ok, far, np.inf)), far.shape)
    cx, cy = gx[ix], gy[iy]
    return Area(x_min_m=cx - half, x_max_m=cx + half, y_min_m=cy - half, y_max_m=cy + half)


def random_network(n_nodes: int, rng: np.random.Generator | int | None = None, *,
                   fov_rad: float = DEFAULT_FOV_RAD,
                   distance_m: tuple[float, float] = (3.0, 7.0),
                   aim_jitter_rad: float = np.deg2rad(15.0),
                   min_separation_m: float = 1.5,
                   min_area_m: float = 1.5,
                   max_tries: int = 1000) -> dict[str, NDArray]:
    """A random network of ``n_nodes`` radars whose fields of view overlap.

    S1 is at the origin with ``phi = 0`` (broadside +y). A centre is drawn in
    front of it (``distance_m`` away, within half its field of view of its
    broadside); every other node stands ``distance_m`` from that centre, in a
    uniformly drawn direction, looking at it with its broadside turned by up
    to ``aim_jitter_rad``. A draw is kept when the nodes are at least
    ``min_separation_m`` apart and their common field of view holds the square
    of side ``min_area_m`` about the centre, 0.5 m from its edges (so that
    :func:`common_area` finds a walking area at least that big); otherwise
    drawn again (``max_tries`` times, then :class:`GeometryError`).
    Returns ``{"S1": pose, "S2": pose, ...}``, poses ``(x_m, y_m, phi_rad)``.
    """
    if isinstance(n_nodes, (bool, np.bool_)) or not isinstance(n_nodes, (int, np.integer)) \
            or n_nodes < 1:
        raise ValidationError(f"n_nodes must be an integer >= 1, got {n_nodes!r}")
    lo, hi = (float(v) for v in distance_m)
    if not (0 < lo <= hi):
        raise ValidationError(f"distance_m={distance_m!r} must be (low, high) with 0 < low <= high")
    gen = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
    limits = dict(fov_rad=fov_rad)
    for _ in range(max_tries):
        d0 = gen.uniform(lo, hi)
        b0 = np.pi / 2 + gen.uniform(-0.5, 0.5) * fov_rad
        centre = d0 * np.array([np.cos(b0), np.sin(b0)])
        poses = {"S1": np.zeros(3)}
        for i in range(2, n_nodes + 1):
            bearing = gen.uniform(-np.pi, np.pi)
            xy = centre + gen.uniform(lo, hi) * np.array([np.cos(bearing), np.sin(bearing)])
            # Broadside (-sin phi, cos phi) toward the centre, turned by the jitter.
            look = bearing + np.pi + gen.uniform(-aim_jitter_rad, aim_jitter_rad)
            phi = float(np.angle(np.exp(1j * (look - np.pi / 2))))
            poses[f"S{i}"] = np.array([xy[0], xy[1], phi])
        xy = np.stack([p[:2] for p in poses.values()])
        gaps = np.linalg.norm(xy[:, None] - xy[None], axis=-1)[np.triu_indices(n_nodes, 1)]
        if gaps.size and gaps.min() < min_separation_m:
            continue
        # The walking square around the centre, with common_area's 0.5 m margin,
        # in every field of view (common_area then finds one at least as big).
        half = 0.5 * min_area_m + 0.5
        g = np.linspace(-half, half, 9)
        square = centre + np.stack(np.meshgrid(g, g), axis=-1).reshape(-1, 2)
        if in_common_field_of_view(square, poses, **limits).all():
            return poses
    raise GeometryError(f"no network of {n_nodes} nodes with a common field of view in "
                        f"{max_tries} draws (distance_m={distance_m!r})")
