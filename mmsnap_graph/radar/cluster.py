"""DBSCAN clustering of a frame's point cloud into one torso centroid per person.

A walking person within 10 m gives a point cloud whose Doppler spreads over
several metres per second: arms and legs swing forward and backward around
the torso's velocity (micro-Doppler), and they sit up to half a metre from the
torso. The plain cluster mean mixes all of that. The paper's torso variant
(section II-A) is designed here as follows:

1. **Position clustering**: DBSCAN (scikit-learn) on the detections' local
   Cartesian positions ``(R sin theta, R cos theta)``. Range is sharp
   (centimetres) but cross-range is coarse (``R * 2 pi / 8 / pi`` at
   broadside: about 1 m at 4 m), so the cross-range coordinate is divided by
   ``cross_range_scale`` (default 3) before DBSCAN: a person is about 0.5 m
   deep but smeared over metres across; two people are separated mostly by
   range.
2. **Torso Doppler**: the mode of the SNR-weighted Doppler density of the
   cluster (a Gaussian kernel one Doppler resolution cell wide, evaluated at
   the points' Dopplers; weights are the SNR in dB, i.e. log-compressed
   power). The torso is the largest reflector (about 0.5 m^2 against
   0.05-0.1 m^2 per limb) and all its points, spread over its depth in
   range, share one velocity, so its Doppler is the dominant mode; the limbs
   spread their weaker returns over many Doppler cells, on both sides of the
   torso. A power-weighted mean would be pulled by any asymmetric limb (the
   swinging leg moves at up to twice the walking speed), and linear power
   weights let one specular point (a foot at 1.5 m) outvote the torso; the
   log-weighted mode avoids both.
3. **Torso points**: the points whose Doppler lies within
   ``torso_doppler_cells`` resolution cells of the mode. The centroid is the
   SNR-weighted mean of their local positions (then converted back to
   range and spatial frequency) and of their Doppler.

Clusters with fewer than ``min_samples`` points are noise (DBSCAN label -1)
and give no centroid, unless ``point_targets`` is on: then a noise point with
an SNR of at least ``point_target_snr_db`` is a **point target**, a centroid
of its own (a corner reflector, a pole: one CFAR peak, which DBSCAN's
three-point minimum would drop). Several people give several centroids (one per
cluster); two people closer than ``eps_m`` merge.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from sklearn.cluster import DBSCAN

from factors.models import detection_to_local

from .._validation import check_count
from ..errors import ConfigurationError
from ..data.recording import Detections

__all__ = ["ClusterConfig", "torso_centroids", "cluster_labels", "point_target_labels",
           "dbscan_small"]

#: Clouds up to this many points use :func:`dbscan_small` (dense, K x K).
_SMALL_MAX = 1500
#: The largest value of each positive option: a cluster radius up to the
#: chain's largest range (m), scales and Doppler cells far beyond any use
#: (a bound, so that a TOML ``1e308`` is named, not carried into the maths).
_BOUNDS = {"eps_m": 1e4, "cross_range_scale": 1e6, "torso_doppler_cells": 1e6}


@dataclass(frozen=True, kw_only=True, slots=True)
class ClusterConfig:
    """Torso-DBSCAN parameters (module docstring).

    eps_m : DBSCAN neighbourhood radius in the scaled position space.
    min_samples : points needed for a core point (and a cluster).
    cross_range_scale : cross-range distances are divided by this.
    torso_doppler_cells : half-width of the torso Doppler window, in Doppler
        resolution cells.
    method : ``"torso"`` (the variant above) or ``"mean"`` (plain SNR-weighted
        cluster mean, for comparison).
    point_targets : an isolated point (DBSCAN noise) with ``snr_db >=
        point_target_snr_db`` is a centroid of its own (default off: people
        give clusters; turn it on for point-like reflectors).
    point_target_snr_db : SNR (dB) a lone point needs to be a point target
        (default 15 dB; points without SNR never qualify).
    """

    eps_m: float = 0.4
    min_samples: int = 3
    cross_range_scale: float = 3.0
    torso_doppler_cells: float = 1.0
    method: str = "torso"
    point_targets: bool = False
    point_target_snr_db: float = 15.0

    def __post_init__(self) -> None:
        for name, top in _BOUNDS.items():
            val = getattr(self, name)
            if isinstance(val, bool) or not (np.isfinite(val) and 0 < val <= top):
                raise ConfigurationError(f"{name}={val!r} must be finite, > 0 and at most "
                                         f"{top:g}")
        check_count(self.min_samples, "min_samples", error=ConfigurationError)
        if not isinstance(self.point_targets, (bool, np.bool_)):
            raise ConfigurationError(f"point_targets={self.point_targets!r} must be True or False")
        if isinstance(self.point_target_snr_db, bool) or not (
                np.isfinite(self.point_target_snr_db) and abs(self.point_target_snr_db) <= 400):
            raise ConfigurationError(f"point_target_snr_db={self.point_target_snr_db!r} must be "
                                     f"a finite number within +-400 dB")
        if self.method not in ("torso", "mean"):
            raise ConfigurationError(f"method={self.method!r} must be 'torso' or 'mean'")


def cluster_labels(range_m: NDArray, omega_rad: NDArray, config: ClusterConfig) -> NDArray:
    """(K,) DBSCAN labels of one frame's detections (-1 = noise)."""
    k = range_m.shape[0]
    if k < config.min_samples:
        return np.full(k, -1, dtype=np.int64)
    return _labels_of_local(detection_to_local(range_m, omega_rad), config)


def _labels_of_local(p: NDArray, config: ClusterConfig) -> NDArray:
    """:func:`cluster_labels` of the points' local positions ``p`` (K, 2)."""
    k = p.shape[0]
    if k < config.min_samples:
        return np.full(k, -1, dtype=np.int64)
    # Rotate each point into (radial, cross-range) of the cloud's mean
    # direction, shrink cross-range, then cluster.
    direction = p.mean(axis=0)
    norm = np.hypot(*direction)
    u = direction / norm if norm > 0 else np.array([0.0, 1.0])
    radial = p @ u
    cross = p @ np.array([-u[1], u[0]])
    feats = np.stack([radial, cross / config.cross_range_scale], axis=-1)
    if k <= _SMALL_MAX:
        return dbscan_small(feats, config.eps_m, int(config.min_samples))
    db = DBSCAN(eps=config.eps_m, min_samples=int(config.min_samples))
    return db.fit_predict(feats).astype(np.int64)


def dbscan_small(feats: NDArray, eps: float, min_samples: int) -> NDArray:
    """(K,) DBSCAN labels of a small point set, the same as scikit-learn's
    ``DBSCAN(eps, min_samples).fit_predict`` (tested against it).

    A frame's cloud holds tens of points, where scikit-learn's set-up costs
    about 2 ms a call, more than the chain's FFTs; this is a dense
    ``(K, K)`` version. Neighbours: distance ``<= eps`` (the point itself
    included, as in scikit-learn); core points: at least ``min_samples``
    neighbours; clusters: connected components of the core points, numbered
    in the order of their first core point; a border point (not core, next
    to a core point) joins the lowest-numbered cluster it touches (scikit-
    learn's expansion order); the rest is noise (-1).
    """
    k = feats.shape[0]
    labels = np.full(k, -1, dtype=np.int64)
    if k == 0:
        return labels
    diff = feats[:, None, :] - feats[None, :, :]
    near = np.einsum("ijk,ijk->ij", diff, diff) <= eps * eps
    core = near.sum(axis=1) >= min_samples
    ci = np.flatnonzero(core)
    if ci.size == 0:
        return labels
    link = near[np.ix_(ci, ci)]
    # Connected components by min-label propagation (K is small).
    comp = np.arange(ci.size)
    while True:
        new = np.where(link, comp[None, :], ci.size).min(axis=1)
        if np.array_equal(new, comp):
            break
        comp = new[new]  # pointer jumping: halves the remaining passes
    _, first, inverse = np.unique(comp, return_index=True, return_inverse=True)
    rank = np.argsort(np.argsort(first))  # clusters in order of their first core point
    labels[ci] = rank[inverse]
    border = np.flatnonzero(~core & near[:, ci].any(axis=1))
    if border.size:
        cand = np.where(near[np.ix_(border, ci)], labels[ci][None, :], np.iinfo(np.int64).max)
        labels[border] = cand.min(axis=1)
    return labels


def point_target_labels(labels: NDArray, snr_db: NDArray | None,
                        config: ClusterConfig) -> NDArray:
    """DBSCAN labels with point targets: with ``config.point_targets``, each
    noise point (label -1) whose ``snr_db >= config.point_target_snr_db``
    gets a new label of its own. Returns a new (K,) int array."""
    out = np.array(labels, dtype=np.int64, copy=True)
    if not config.point_targets or snr_db is None:
        return out
    lone = np.flatnonzero((out < 0) & (np.asarray(snr_db) >= config.point_target_snr_db))
    first = int(out.max()) + 1 if out.size else 0
    out[lone] = first + np.arange(lone.size)
    return out


def _torso_of_cluster(p, dop, w, config: ClusterConfig, doppler_res: float):
    if config.method == "mean" or dop.size == 1:
        sel = np.ones(dop.size, bool)
    else:
        # Power-weighted Gaussian kernel density of Doppler, at the points.
        diff = (dop[:, None] - dop[None, :]) / doppler_res
        density = np.exp(-0.5 * diff**2) @ w
        mode = dop[np.argmax(density)]
        sel = np.abs(dop - mode) <= config.torso_doppler_cells * doppler_res
    ws = w[sel] / w[sel].sum()
    pos = ws @ p[sel]
    return pos, float(ws @ dop[sel])


def torso_centroids(
    point_cloud: Detections, config: ClusterConfig, *, doppler_resolution_mps: float
) -> Detections:
    """One centroid per cluster per frame from a point cloud (module docstring).

    point_cloud : detections of any number of frames (``snr_db`` is used as
        the power weight when present, else equal weights).
    Returns centroids as :class:`Detections` (``snr_db`` = the strongest
    point of the torso set; ``target_id`` = -1, unlabelled).
    """
    if len(point_cloud) == 0:
        return Detections.empty()
    out_f, out_r, out_w, out_v, out_s = [], [], [], [], []
    frames = point_cloud.frame
    order = np.argsort(frames, kind="stable")
    bounds = np.flatnonzero(np.diff(frames[order])) + 1
    # Positions and weights of all points at once (elementwise, the same
    # numbers as per frame), in frame order.
    p_all = detection_to_local(point_cloud.range_m[order], point_cloud.omega_rad[order])
    dop_all = point_cloud.doppler_mps[order]
    has_snr = point_cloud.snr_db is not None
    snr_all = point_cloud.snr_db[order] if has_snr else np.zeros(order.size)
    # Log-compressed weights (SNR in dB above 0): one strong specular
    # point (a foot at close range) must not outvote the many torso points.
    w_all = np.maximum(snr_all, 0.0) + 1e-3
    lone_ok = config.point_targets and has_snr
    starts = np.concatenate([[0], bounds]).tolist()
    stops = np.concatenate([bounds, [order.size]]).tolist()
    for a, b in zip(starts, stops):
        if b - a < config.min_samples and not lone_ok:
            continue  # all DBSCAN noise, no point targets: no centroid
        p, dop, snr, w = p_all[a:b], dop_all[a:b], snr_all[a:b], w_all[a:b]
        labels = point_target_labels(_labels_of_local(p, config),
                                     snr if has_snr else None, config)
        if not np.any(labels >= 0):
            continue
        for lab in np.unique(labels[labels >= 0]):
            m = labels == lab
            pos, v = _torso_of_cluster(p[m], dop[m], w[m], config, doppler_resolution_mps)
            r = float(np.hypot(*pos))
            if r <= 0:
                continue
            out_f.append(frames[order[a]])
            out_r.append(r)
            out_w.append(float(np.clip(np.pi * pos[0] / r, -np.pi, np.pi)))
            out_v.append(v)
            out_s.append(float(snr[m].max()))
    if not out_f:
        return Detections.empty()
    n = len(out_f)
    return Detections(frame=np.asarray(out_f), range_m=np.asarray(out_r),
                      omega_rad=np.asarray(out_w), doppler_mps=np.asarray(out_v),
                      snr_db=np.asarray(out_s), target_id=np.full(n, -1))
