"""What a view of the fused people shows, as plain arrays in the reference
frame (S1's, docs/CONVENTIONS.md): the geometry that the Foxglove log
(:mod:`.foxglove_log`) and ``mmsnap plot`` (:mod:`.plot`) share.

- :func:`covariance_ellipse`: the ``n_sigma`` contour of a position
  covariance, ``{p : (p - c)^T P^-1 (p - c) = n_sigma^2}``;
- :func:`field_of_view`: a radar's field of view as a closed outline (its
  position, an arc of ``range_m`` from ``-half_angle`` to ``+half_angle``
  about the boresight, its position again);
- :func:`detections_xy`: a node's detections ``(range, omega)`` in the
  reference frame;
- :class:`TrackHistory`: the recent positions of each person id, bounded;
- :func:`id_color`: one colour per person id, the same in every view.
"""

from __future__ import annotations

from collections import deque

import numpy as np
from numpy.typing import ArrayLike, NDArray

from factors.models import detection_to_global, local_to_global

from ...errors import ValidationError

__all__ = ["ELLIPSE_SIGMA", "ELLIPSE_POINTS", "FOV_HALF_ANGLE_RAD", "FOV_RANGE_M",
           "covariance_ellipse", "field_of_view", "boresight", "detections_xy", "TrackHistory",
           "id_color", "node_color"]

#: The people's ellipses are their 2-sigma position contours (86 % of a 2D Gaussian).
ELLIPSE_SIGMA = 2.0
#: Points on an ellipse's outline.
ELLIPSE_POINTS = 48
#: Half the azimuth field of view of TI's xWR1843 / xWR6843 boards (+-60 degrees).
FOV_HALF_ANGLE_RAD = float(np.deg2rad(60.0))
#: The range the field of view is drawn to when nothing else says.
FOV_RANGE_M = 6.0

# tab10, as matplotlib draws it: the same colours in Foxglove and in plots.
_PALETTE = ((0.122, 0.467, 0.706), (1.0, 0.498, 0.055), (0.173, 0.627, 0.173),
            (0.839, 0.153, 0.157), (0.580, 0.404, 0.741), (0.549, 0.337, 0.294),
            (0.890, 0.467, 0.761), (0.498, 0.498, 0.498), (0.737, 0.741, 0.133),
            (0.090, 0.745, 0.812))
# Board colours: greys and muted tones, apart from the people's.
_NODE_PALETTE = ((0.25, 0.25, 0.25), (0.65, 0.45, 0.15), (0.20, 0.50, 0.60),
                 (0.50, 0.30, 0.55), (0.35, 0.55, 0.30), (0.65, 0.35, 0.35))


def id_color(person_id: int) -> tuple[float, float, float]:
    """RGB in [0, 1] of a person id (matplotlib's tab10, cycling)."""
    return _PALETTE[int(person_id) % len(_PALETTE)]


def node_color(index: int) -> tuple[float, float, float]:
    """RGB in [0, 1] of the ``index``-th node's points."""
    return _NODE_PALETTE[int(index) % len(_NODE_PALETTE)]


def covariance_ellipse(center_m: ArrayLike, covariance_m2: ArrayLike, *,
                       n_sigma: float = ELLIPSE_SIGMA, n_points: int = ELLIPSE_POINTS) -> NDArray:
    """The ``n_sigma`` contour of a 2D Gaussian, ``(n_points, 2)``.

    center_m : (2,) the mean; covariance_m2 : (2, 2) symmetric positive
    semi-definite (a singular one gives a flat ellipse). The points are
    ``c + n_sigma V diag(sqrt(w)) (cos t, sin t)`` with ``P = V diag(w) V^T``,
    ``t`` evenly spaced over a turn (the first point not repeated).
    """
    c = np.asarray(center_m, dtype=float)
    p = np.asarray(covariance_m2, dtype=float)
    if c.shape != (2,) or p.shape != (2, 2):
        raise ValidationError(f"center_m must be (2,) and covariance_m2 (2, 2), got {c.shape} "
                              f"and {p.shape}")
    if not (np.all(np.isfinite(c)) and np.all(np.isfinite(p))):
        raise ValidationError("center_m and covariance_m2 must be finite")
    w, v = np.linalg.eigh(0.5 * (p + p.T))
    if w.min() < -1e-12 * max(abs(w.max()), 1e-300):
        raise ValidationError(f"covariance_m2 is not positive semi-definite (eigenvalues {w})")
    t = np.linspace(0.0, 2.0 * np.pi, int(n_points), endpoint=False)
    circle = np.stack([np.cos(t), np.sin(t)], axis=-1)
    return c + float(n_sigma) * (circle * np.sqrt(np.clip(w, 0.0, None))) @ v.T


def field_of_view(pose: ArrayLike, *, half_angle_rad: float = FOV_HALF_ANGLE_RAD,
                  range_m: float = FOV_RANGE_M, n_arc: int = 25) -> NDArray:
    """A radar's field of view as a closed outline ``(n_arc + 2, 2)`` in the
    reference frame: its position, the arc at ``range_m`` from
    ``theta = -half_angle_rad`` to ``+half_angle_rad`` (theta from the
    boresight, positive toward the array axis), its position again."""
    theta = np.linspace(-half_angle_rad, half_angle_rad, int(n_arc))
    arc = local_to_global(np.stack([range_m * np.sin(theta), range_m * np.cos(theta)], -1),
                          np.asarray(pose, dtype=float))
    xy = np.asarray(pose, dtype=float)[:2]
    return np.vstack([xy, arc, xy])


def boresight(pose: ArrayLike, length_m: float = 0.5) -> NDArray:
    """``(2, 2)``: the radar's position and the point ``length_m`` along its
    boresight ``(-sin phi, cos phi)``."""
    x, y, phi = (float(v) for v in np.asarray(pose, dtype=float))
    return np.array([[x, y], [x - length_m * np.sin(phi), y + length_m * np.cos(phi)]])


def detections_xy(detections, pose: ArrayLike) -> NDArray:
    """``(K, 2)`` positions of a node's detections (anything with
    ``range_m`` and ``omega_rad``, or ``(K, 3)`` rows) in the reference frame."""
    if hasattr(detections, "range_m"):
        r, w = detections.range_m, detections.omega_rad
    else:
        z = np.asarray(detections, dtype=float).reshape(-1, 3)
        r, w = z[:, 0], z[:, 1]
    if len(r) == 0:
        return np.zeros((0, 2))
    return detection_to_global(np.asarray(r, float), np.asarray(w, float),
                               np.asarray(pose, dtype=float))


class TrackHistory:
    """Each person id's positions over the last ``max_age_s`` seconds (at
    most ``max_points`` each); an id not seen for ``max_age_s`` is dropped,
    so the memory stays bounded however long the session runs."""

    def __init__(self, max_age_s: float = 10.0, max_points: int = 400) -> None:
        if not (np.isfinite(max_age_s) and max_age_s > 0):
            raise ValidationError(f"max_age_s={max_age_s!r} must be finite and > 0")
        self.max_age_s = float(max_age_s)
        self.max_points = int(max_points)
        self._tracks: dict[int, deque] = {}

    def update(self, time_s: float, ids: ArrayLike, xy_m: ArrayLike) -> None:
        """Add the positions ``xy_m (T, 2)`` of the ids ``(T,)`` at ``time_s``."""
        for tid, p in zip(np.asarray(ids).tolist(), np.asarray(xy_m, float).reshape(-1, 2)):
            self._tracks.setdefault(int(tid), deque(maxlen=self.max_points)).append(
                (float(time_s), float(p[0]), float(p[1])))
        old = float(time_s) - self.max_age_s
        for tid in list(self._tracks):
            q = self._tracks[tid]
            while q and q[0][0] < old:
                q.popleft()
            if not q:
                del self._tracks[tid]

    def lines(self) -> dict[int, NDArray]:
        """id -> ``(L, 2)`` its positions, oldest first."""
        return {tid: np.array([(x, y) for _, x, y in q]) for tid, q in self._tracks.items()}
