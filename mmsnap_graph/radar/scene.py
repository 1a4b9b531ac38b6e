"""Per-node filters of real point clouds: static scene, one cluster per body,
multipath ghosts, target existence (docs/TI.md, "Static scene and ghosts").

Real TI point clouds carry what the simulator's people do not: zero-Doppler
points of walls and furniture (the out-of-box demos leave static clutter
removal off), reflections via walls (a weaker copy of a person further along
the same bearing), bodies split into several clusters, and one-frame blips.
Each filter here works in one node's local plane (no other node, no pose) and
says what it dropped:

1. :func:`static_scene_mask` (points): a background occupancy map learned over
   the recording. The plane is cut into ``cell_m`` cells and the recording
   into ``window_s`` windows; a cell is background when zero-Doppler points
   (``|doppler| <= zero_doppler_mps``) fall in it in at least
   ``min_occupancy`` of the windows (and at least ``min_windows``). Its
   zero-Doppler points, and those of its neighbouring cells, are dropped; a
   moving person crossing it keeps their moving points, and a person who
   stands still elsewhere keeps theirs. A person who stands in one place for
   a large part of the recording becomes background (as in TI's tracker).
2. :func:`merge_close_centroids` (centroids): an extent prior: centroids of one
   frame closer than ``body_m`` (a merge radius) are one body, merged into
   their SNR-weighted mean.
3. :func:`ghost_mask` (centroids): a multipath ghost is a weaker centroid
   further along the same bearing (``|sin theta_a - sin theta_b| <=
   bearing_sin``, at least ``behind_m`` further) with a consistent Doppler
   (within ``ghost_doppler_mps``): the path via a wall is longer, at nearly
   the same angle and speed.
4. :func:`existence_mask` (centroids): a target exists when other frames within
   ``existence_window_s`` hold a centroid where it could have walked
   (``body_m + max_speed_mps * dt``) in at least ``existence_min_frames``
   frames; one-frame blips are dropped.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from factors.models import detection_to_local

from .._validation import check_count
from ..data.recording import Detections
from ..data.body import SCENE_MERGE_RADIUS_M
from ..errors import ConfigurationError

__all__ = ["SceneConfig", "SceneReport", "static_scene_mask", "merge_close_centroids",
           "ghost_mask", "existence_mask", "filter_points", "filter_centroids"]


#: Physical ranges of the thresholds (m, s, m/s, sin): a 1e308 s window or a
#: 1e-300 m cell is an infinite number of windows or cells.
_BOUNDS = {"zero_doppler_mps": (0.0, 1e4), "cell_m": (1e-3, 1e3), "window_s": (1e-3, 3600.0),
           "body_m": (0.0, 1e3), "bearing_sin": (0.0, 2.0), "behind_m": (0.0, 1e4),
           "ghost_doppler_mps": (0.0, 1e4), "existence_window_s": (0.0, 3600.0),
           "max_speed_mps": (0.0, 1e4)}
_MAX_FRAMES = 1_000_000


@dataclass(frozen=True, kw_only=True, slots=True)
class SceneConfig:
    """Switches and thresholds of the scene filters (module docstring).

    static, merge, ghosts, existence : each filter on (True) or off.
    zero_doppler_mps : a point this slow or slower is static (m/s).
    cell_m : background map cell (m). window_s : occupancy window (s).
    min_occupancy : fraction of windows a background cell is occupied in.
    min_windows : and at least this many windows.
    body_m : merge radius (m): a node's centroids of one frame closer than
        this are one body (default
        :data:`~mmsnap_graph.data.body.SCENE_MERGE_RADIUS_M`, which says why).
    bearing_sin : same bearing, in sin(azimuth). behind_m : a ghost is at least
    this much further (m). ghost_doppler_mps : and its Doppler this close (m/s).
    existence_window_s : half-width of the existence window (s).
    existence_min_frames : frames of that window that must confirm a target.
    max_speed_mps : fastest walker (m/s), for the existence gate.
    """

    static: bool = True
    merge: bool = True
    ghosts: bool = True
    existence: bool = True
    zero_doppler_mps: float = 0.05
    cell_m: float = 0.25
    window_s: float = 1.0
    min_occupancy: float = 0.2
    min_windows: int = 3
    body_m: float = SCENE_MERGE_RADIUS_M
    bearing_sin: float = 0.1
    behind_m: float = 0.3
    ghost_doppler_mps: float = 0.3
    existence_window_s: float = 0.5
    existence_min_frames: int = 2
    max_speed_mps: float = 2.0

    def __post_init__(self) -> None:
        for name in ("static", "merge", "ghosts", "existence"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise ConfigurationError(f"{name}={getattr(self, name)!r} must be True or False")
        for name in ("zero_doppler_mps", "min_occupancy", "bearing_sin", "behind_m",
                     "ghost_doppler_mps", "max_speed_mps"):
            val = getattr(self, name)
            if not (np.isfinite(val) and val >= 0):
                raise ConfigurationError(f"{name}={val!r} must be finite and >= 0")
        for name in ("cell_m", "window_s", "body_m", "existence_window_s"):
            val = getattr(self, name)
            if not (np.isfinite(val) and val > 0):
                raise ConfigurationError(f"{name}={val!r} must be finite and > 0")
        if self.min_occupancy > 1:
            raise ConfigurationError(f"min_occupancy={self.min_occupancy!r} is a fraction "
                                     "of the windows, in [0, 1]")
        for name in ("min_windows", "existence_min_frames"):
            check_count(getattr(self, name), name, 0, _MAX_FRAMES, error=ConfigurationError)
        for name, (low, high) in _BOUNDS.items():
            val = getattr(self, name)
            if not low <= val <= high:
                raise ConfigurationError(f"{name}={val!r} must be in [{low:g}, {high:g}] "
                                         f"(beyond, it is not physical: check the unit)")


@dataclass(frozen=True, slots=True)
class SceneReport:
    """What the filters dropped on one node: ``dropped`` filter -> count,
    ``of`` filter -> what it looked at (points or centroids)."""

    dropped: dict = field(default_factory=dict)
    of: dict = field(default_factory=dict)

    def text(self) -> str:
        words = {"static": "static-scene points", "merge": "centroids merged (one body)",
                 "ghosts": "multipath ghosts", "existence": "centroids without existence"}
        parts = [f"{self.dropped[k]} of {self.of[k]} {words[k]}" for k in words
                 if k in self.dropped]
        return "dropped " + ", ".join(parts) if parts else "no scene filter"


def _local(det: Detections) -> NDArray:
    return detection_to_local(det.range_m, det.omega_rad)


def static_scene_mask(points: Detections, frame_period_s: float,
                      config: SceneConfig = SceneConfig()) -> NDArray:
    """(K,) True for the points kept: those not static in background cells."""
    keep = np.ones(len(points), dtype=bool)
    still = np.abs(points.doppler_mps) <= config.zero_doppler_mps
    if not np.any(still):
        return keep
    cell = np.floor(_local(points) / config.cell_m).astype(np.int64)
    per_window = max(1, int(round(config.window_s / frame_period_s)))
    window = (points.frame - points.frame.min()) // per_window
    n_windows = int(window.max()) + 1
    need = max(config.min_occupancy * n_windows, config.min_windows, 1)
    # Distinct (cell, window) pairs of static points -> windows per cell.
    cells, inverse = np.unique(cell[still], axis=0, return_inverse=True)
    pairs = np.unique(np.stack([inverse.ravel(), window[still]], axis=1), axis=0)
    occupancy = np.bincount(pairs[:, 0], minlength=len(cells))
    background = cells[occupancy >= need]
    if not len(background):
        return keep
    # Quantised positions jitter across cell borders: the neighbours count too.
    grown = (background[:, None, :] + np.array([(i, j) for i in (-1, 0, 1)
                                                for j in (-1, 0, 1)])[None]).reshape(-1, 2)
    grown = np.unique(grown, axis=0)
    hit = (cell[:, None, :] == grown[None]).all(axis=-1).any(axis=1)
    keep[still & hit] = False
    return keep


def _frame_groups(frame: NDArray):
    order = np.argsort(frame, kind="stable")
    bounds = np.flatnonzero(np.diff(frame[order])) + 1
    return np.split(order, bounds)


def _snr_weights(det: Detections) -> NDArray:
    if det.snr_db is None:
        return np.ones(len(det))
    return np.maximum(det.snr_db, 0.0) + 1e-3


def merge_close_centroids(cents: Detections, config: SceneConfig = SceneConfig()
                          ) -> tuple[Detections, int]:
    """Centroids of one frame closer than ``body_m`` merged (transitively)
    into their SNR-weighted mean; returns the centroids and how many merged
    away."""
    if len(cents) < 2:
        return cents, 0
    p, w = _local(cents), _snr_weights(cents)
    label = np.arange(len(cents))
    for rows in _frame_groups(cents.frame):
        if rows.size < 2:
            continue
        d = np.hypot(*(p[rows, None, :] - p[None, rows, :]).transpose(2, 0, 1))
        for i in range(rows.size):                     # union of close pairs
            for j in np.flatnonzero(d[i, i + 1:] < config.body_m) + i + 1:
                a, b = label[rows[i]], label[rows[j]]
                label[label == max(a, b)] = min(a, b)
    groups = np.unique(label)
    if groups.size == len(cents):
        return cents, 0
    out = {k: [] for k in ("frame", "range_m", "omega_rad", "doppler_mps", "snr_db")}
    for g in groups:
        m = label == g
        ww = w[m] / w[m].sum()
        pos = ww @ p[m]
        r = float(np.hypot(*pos))
        out["frame"].append(cents.frame[m][0])
        out["range_m"].append(r)
        out["omega_rad"].append(float(np.clip(np.pi * pos[0] / r, -np.pi, np.pi)) if r > 0
                                else 0.0)
        out["doppler_mps"].append(float(ww @ cents.doppler_mps[m]))
        out["snr_db"].append(float(cents.snr_db[m].max()) if cents.snr_db is not None
                             else np.nan)
    snr = np.asarray(out.pop("snr_db"))
    snr = snr if cents.snr_db is not None else None
    order = np.argsort(out["frame"], kind="stable")
    merged = Detections(**{k: np.asarray(v)[order] for k, v in out.items()},
                        snr_db=None if snr is None else snr[order],
                        target_id=np.full(groups.size, -1))
    return merged, len(cents) - groups.size


def ghost_mask(cents: Detections, config: SceneConfig = SceneConfig()) -> NDArray:
    """(K,) True for the centroids kept: not a weaker copy of another
    centroid of its frame further along the same bearing."""
    keep = np.ones(len(cents), dtype=bool)
    sin = np.clip(cents.omega_rad / np.pi, -1.0, 1.0)
    w = _snr_weights(cents)
    for rows in _frame_groups(cents.frame):
        for i in rows:
            for j in rows:
                if (i != j and abs(sin[i] - sin[j]) <= config.bearing_sin
                        and cents.range_m[j] - cents.range_m[i] >= config.behind_m
                        and w[j] < w[i]
                        and abs(cents.doppler_mps[j] - cents.doppler_mps[i])
                        <= config.ghost_doppler_mps):
                    keep[j] = False
    return keep


def existence_mask(cents: Detections, frame_period_s: float,
                   config: SceneConfig = SceneConfig()) -> NDArray:
    """(K,) True for the centroids whose target exists: confirmed by a
    centroid within reach in ``existence_min_frames`` other frames of the
    window."""
    n = len(cents)
    if n == 0 or config.existence_min_frames == 0:
        return np.ones(n, dtype=bool)
    half = max(1, int(round(config.existence_window_s / frame_period_s)))
    p = _local(cents)
    order = np.argsort(cents.frame, kind="stable")
    f = cents.frame[order]
    support = np.zeros(n, dtype=np.int64)
    for k, i in enumerate(order):
        lo, hi = np.searchsorted(f, f[k] - half), np.searchsorted(f, f[k] + half, side="right")
        js = order[lo:hi]
        dt = np.abs(cents.frame[js] - cents.frame[i])
        near = (dt > 0) & (np.hypot(*(p[js] - p[i]).T)
                           <= config.body_m + config.max_speed_mps * dt * frame_period_s)
        support[i] = np.unique(cents.frame[js][near]).size
    return support >= config.existence_min_frames


def _count(report: SceneReport, name: str, kept: NDArray) -> None:
    report.dropped[name] = int(np.sum(~kept))
    report.of[name] = int(kept.size)


def filter_points(points: Detections, frame_period_s: float, config: SceneConfig,
                  report: SceneReport) -> Detections:
    """The static-scene filter when on (counted in ``report``)."""
    if not config.static or len(points) == 0:
        return points
    keep = static_scene_mask(points, frame_period_s, config)
    _count(report, "static", keep)
    return points.select(keep) if hasattr(points, "select") else _select(points, keep)


def _select(det: Detections, keep: NDArray) -> Detections:
    pick = lambda a: None if a is None else a[keep]
    return Detections(frame=det.frame[keep], range_m=det.range_m[keep],
                      omega_rad=det.omega_rad[keep], doppler_mps=det.doppler_mps[keep],
                      snr_db=pick(det.snr_db), target_id=pick(det.target_id))


def filter_centroids(cents: Detections, frame_period_s: float, config: SceneConfig,
                     report: SceneReport) -> Detections:
    """Merge, ghost and existence filters in that order, each when on."""
    if config.merge:
        before = len(cents)
        cents, merged = merge_close_centroids(cents, config)
        report.dropped["merge"], report.of["merge"] = merged, before
    if config.ghosts and len(cents):
        keep = ghost_mask(cents, config)
        _count(report, "ghosts", keep)
        cents = _select(cents, keep)
    if config.existence and len(cents):
        keep = existence_mask(cents, frame_period_s, config)
        _count(report, "existence", keep)
        cents = _select(cents, keep)
    return cents
