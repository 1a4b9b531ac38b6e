"""The whole per-node chain on in-memory nodes and recordings, and on files:
cube -> point cloud -> torso centroids (:mod:`mmsnap_graph.radar.chain`) -> local EKF tracks
(:mod:`mmsnap_graph.tracking.ekf`).

- :func:`process_node` / :func:`process_recording`: from each node's cube
  (else its point cloud, else its centroids);
- :func:`cluster_node`: from a point cloud (torso DBSCAN, then the EKF), for
  recordings stored at the point-cloud level; a *sparse* cloud (fewer than
  :data:`SPARSE_POINTS_PER_FRAME` points in its median non-empty frame once
  the scene filters have dropped the static scene, as
  TI's out-of-box demo gives: 2-3 points per person) is clustered with
  ``min_samples=1`` (:func:`sparse_cluster_config`): the torso DBSCAN's
  three-point minimum would drop most of it, and the calibration with it
  (tests/sim/real/test_sparse.py);
- :func:`track_node` / :func:`track_recording`: tracks from the centroids
  only;
- :func:`process_file`: an HDF5 recording, cubes streamed frame by frame,
  levels written back atomically (the ``mmsnap process`` command).
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._atomic import check_output_path, recording_lock
from ..data.radar_config import TABLE_I
from ..calibration.noise.estimate import MIN_DOF, temporal_noise
from ..data.recording import Detections, NodeData, Recording
from ..errors import FileFormatError, ValidationError
from ..io import iter_cubes, read_cube_frames, read_recording, update_recording
from ..radar.chain import ChainConfig, ChainResult, process_cubes, unambiguous_speed_mps
from ..radar.cluster import torso_centroids
from ..radar.scene import SceneConfig, SceneReport, filter_centroids, filter_points
from ..tracking.ekf import EkfConfig, frames_to_step, track_centroids

__all__ = ["NodeReport", "process_node", "process_recording", "cluster_node", "track_node",
           "track_recording", "process_file", "sparse_cluster_config", "SPARSE_POINTS_PER_FRAME"]

#: A point cloud whose median non-empty frame holds fewer points than this
#: is sparse (:func:`sparse_cluster_config`). The simulator's dense clouds of
#: two walkers hold 20-40 per frame, TI's demo clouds 2-3 per person.
SPARSE_POINTS_PER_FRAME = 6


@dataclass(frozen=True, kw_only=True, slots=True)
class NodeReport:
    """What happened to one node: ``level`` is ``"cube"`` (full chain),
    ``"point_cloud"`` (clustering and tracking), ``"centroids"`` (tracking
    only) or ``"none"`` (nothing to process);
    ``chain`` is the chain's result for cube-level processing."""

    name: str
    level: str
    n_frames: int
    n_points: int
    n_centroids: int
    n_tracks: int
    success: bool
    message: str
    chain: ChainResult | None = None


#: Where the local EKF's measurement noise comes from: ``"data"`` (default):
#: each node's own centroids (temporal differences,
#: :func:`~mmsnap_graph.calibration.noise.estimate.temporal_noise`), every
#: component they identify; ``"config"``: ``EkfConfig.measurement_std`` as given.
EKF_NOISE_SOURCES = ("data", "config")


def ekf_noise_from_centroids(ekf: EkfConfig, centroids: Detections | None) -> EkfConfig:
    """``ekf`` with each measurement sigma (range, omega, Doppler) that the
    node's own centroids identify (at least ``MIN_DOF`` differences); the
    others keep ``ekf.measurement_std``."""
    if centroids is None or len(centroids) == 0:
        return ekf
    sig, counts = temporal_noise(centroids)
    std = np.asarray(ekf.measurement_std, dtype=float)
    ok = np.isfinite(sig) & (sig > 0) & (counts >= MIN_DOF)
    if not np.any(ok):
        return ekf
    return dataclasses.replace(ekf, measurement_std=tuple(float(v) for v in np.where(ok, sig, std)))


def _ekf_for(ekf: EkfConfig | None, frame_period_s: float, centroids: Detections | None = None,
             ekf_noise: str = "data") -> EkfConfig:
    if ekf_noise not in EKF_NOISE_SOURCES:
        raise ValidationError(f"ekf_noise must be one of {EKF_NOISE_SOURCES}, got {ekf_noise!r}")
    ekf = EkfConfig() if ekf is None else ekf
    ekf = dataclasses.replace(ekf, frame_period_s=float(frame_period_s))
    return ekf_noise_from_centroids(ekf, centroids) if ekf_noise == "data" else ekf


def _frames_span(frames: np.ndarray, ekf: EkfConfig | None = None) -> np.ndarray | None:
    """The frames the EKF steps through: those present, and the first frames
    of each gap while a track could still coast (a gap of 10^12 frames is not
    10^12 steps; :func:`~mmsnap_graph.tracking.ekf.frames_to_step`)."""
    if frames.size == 0:
        return None
    return frames_to_step(frames, EkfConfig() if ekf is None else ekf)


def process_node(
    node: NodeData,
    frame_period_s: float,
    *,
    config: ChainConfig | None = None,
    ekf: EkfConfig | None = None,
    progress: bool = False,
    ekf_noise: str = "data",
) -> tuple[NodeData, NodeReport]:
    """Fill a node's point cloud, centroids and tracks from its cube.

    frame_period_s : the recording's frame period (the EKF's T).
    config : the chain's configuration (default ``ChainConfig()``); ekf : the
    EKF's (default ``EkfConfig()``, its frame period set to ``frame_period_s``).
    ekf_noise : ``"data"`` (default): the EKF's measurement sigmas from the
    node's own centroids where they identify them (:func:`ekf_noise_from_centroids`);
    ``"config"``: ``ekf.measurement_std`` as given.
    Returns the new node and a :class:`NodeReport`. A node without a cube
    raises :class:`ValidationError` (use :func:`track_node`).
    """
    if node.cube is None:
        raise ValidationError(f"nodes[{node.name}] has no cube; use track_node for centroids")
    result = process_cubes(node.cube, node.radar, config, frames=node.cube_frame,
                           progress=progress, desc=f"{node.name} chain")
    tracker = _ekf_for(ekf, frame_period_s, result.centroids, ekf_noise)
    if tracker.doppler_wrap_mps is None:
        # The chain's Doppler is unambiguous only within +-U: the EKF wraps its
        # Doppler innovation modulo 2 U.
        tracker = dataclasses.replace(
            tracker, doppler_wrap_mps=unambiguous_speed_mps(node.radar, config))
    tracks = track_centroids(result.centroids, tracker, frames=_frames_span(node.cube_frame, ekf))
    new = dataclasses.replace(node, point_cloud=result.point_cloud, centroids=result.centroids,
                              tracks=tracks)
    return new, NodeReport(name=node.name, level="cube", n_frames=int(node.cube.shape[0]),
                           n_points=len(result.point_cloud), n_centroids=len(result.centroids),
                           n_tracks=int(tracks.track_ids.size), success=result.success,
                           message=result.message, chain=result)


def sparse_cluster_config(point_cloud: Detections, config: ChainConfig,
                          sparse: bool | None = None) -> tuple[ChainConfig, bool]:
    """``config`` for a sparse cloud: its clustering with ``min_samples=1``
    (every DBSCAN cluster of one or more points is a centroid; a person's
    2-3 points within ``eps_m`` are one). ``sparse`` None (auto): when the
    median non-empty frame of ``point_cloud`` holds fewer than
    :data:`SPARSE_POINTS_PER_FRAME` points; True / False: always / never.
    Returns the configuration and whether it was changed."""
    if sparse is None:
        # Counts of the frames present (a frame number of 2^31, one flipped
        # bit, made a bincount over the span ask for 16 GiB).
        counts = np.unique(point_cloud.frame, return_counts=True)[1]
        sparse = bool(counts.size) and float(np.median(counts)) < SPARSE_POINTS_PER_FRAME
    if not sparse or config.cluster.min_samples == 1:
        return config, False
    return dataclasses.replace(config, cluster=dataclasses.replace(config.cluster,
                                                                   min_samples=1)), True


def cluster_node(
    node: NodeData,
    frame_period_s: float,
    *,
    config: ChainConfig | None = None,
    ekf: EkfConfig | None = None,
    ekf_noise: str = "data",
    sparse: bool | None = None,
    scene: SceneConfig | None = SceneConfig(),
) -> tuple[NodeData, NodeReport]:
    """Fill a node's centroids (torso DBSCAN with ``config.cluster``) and
    tracks from its point cloud (``ekf_noise``: :func:`process_node`;
    ``sparse``: :func:`sparse_cluster_config`, None: detected). ``scene``:
    the scene filters of real clouds (:mod:`mmsnap_graph.radar.scene`: static
    scene, one cluster per body, multipath ghosts, existence; None: none);
    the stored point cloud is kept whole."""
    if node.point_cloud is None:
        raise ValidationError(f"nodes[{node.name}] has no point cloud to cluster")
    radar = TABLE_I if node.radar is None else node.radar
    scene = SceneConfig(static=False, merge=False, ghosts=False,
                        existence=False) if scene is None else scene
    report = SceneReport()
    points = filter_points(node.point_cloud, frame_period_s, scene, report)
    # Sparse or not by the points that are clustered: a wall's zero-Doppler
    # points, which the static-scene filter drops, say nothing about how many
    # points a person gives (the first half of the two-person recording: S2's
    # median frame 6 points with them, 3 without).
    config, thinned = sparse_cluster_config(points, ChainConfig() if config is None else config,
                                            sparse)
    cents = torso_centroids(points, config.cluster,
                            doppler_resolution_mps=radar.doppler_resolution_mps)
    cents = filter_centroids(cents, frame_period_s, scene, report)
    frames = node.point_cloud.frame
    tracks = track_centroids(cents, _ekf_for(ekf, frame_period_s, cents, ekf_noise),
                             frames=_frames_span(frames, ekf))
    new = dataclasses.replace(node, centroids=cents, tracks=tracks)
    return new, NodeReport(name=node.name, level="point_cloud",
                           n_frames=int(np.unique(frames).size),
                           n_points=len(node.point_cloud), n_centroids=len(cents),
                           n_tracks=int(tracks.track_ids.size), success=True,
                           message=f"{len(node.point_cloud)} points clustered"
                           + (" (sparse cloud: min_samples=1)" if thinned else "")
                           + ("; " + report.text() if report.dropped else ""))


def _from_stored_levels(node: NodeData, frame_period_s: float, config, ekf, centroids_only,
                        ekf_noise="data", sparse=None, scene=SceneConfig()):
    """The highest stored level below the cube: point cloud, else centroids."""
    if node.point_cloud is not None and not centroids_only:
        return cluster_node(node, frame_period_s, config=config, ekf=ekf, ekf_noise=ekf_noise,
                            sparse=sparse, scene=scene)
    if node.centroids is not None:
        return track_node(node, frame_period_s, ekf=ekf, ekf_noise=ekf_noise)
    return None


def track_node(node: NodeData, frame_period_s: float, *, ekf: EkfConfig | None = None,
               ekf_noise: str = "data") -> tuple[NodeData, NodeReport]:
    """Fill a node's tracks from its centroids (no cube needed;
    ``ekf_noise``: :func:`process_node`)."""
    if node.centroids is None:
        raise ValidationError(f"nodes[{node.name}] has no centroids to track")
    tracks = track_centroids(node.centroids, _ekf_for(ekf, frame_period_s, node.centroids,
                                                      ekf_noise))
    new = dataclasses.replace(node, tracks=tracks)
    n = len(node.centroids)
    return new, NodeReport(name=node.name, level="centroids",
                           n_frames=int(np.unique(node.centroids.frame).size), n_points=0,
                           n_centroids=n, n_tracks=int(tracks.track_ids.size), success=True,
                           message=f"{n} centroids tracked")


def _each_node(recording: Recording, fn) -> tuple[Recording, dict[str, NodeReport]]:
    reports: dict[str, NodeReport] = {}
    rec = recording
    for name, node in recording.nodes.items():
        out = fn(node)
        if out is None:
            reports[name] = NodeReport(name=name, level="none", n_frames=0, n_points=0,
                                       n_centroids=0, n_tracks=0, success=False,
                                       message="no cube, point cloud or centroids")
            continue
        new, rep = out
        rec = rec.with_node(new)
        reports[name] = rep
    return rec, reports


def process_recording(
    recording: Recording,
    *,
    config: ChainConfig | None = None,
    ekf: EkfConfig | None = None,
    progress: bool = False,
    ekf_noise: str = "data",
    sparse: bool | None = None,
    scene: SceneConfig | None = SceneConfig(),
) -> tuple[Recording, dict[str, NodeReport]]:
    """Run the chain on every node from the highest level it holds: the cube,
    else the point cloud, else the centroids; nodes with none are reported,
    unchanged. ``sparse``, ``scene``: point clouds' clustering
    (:func:`cluster_node`)."""
    fp = recording.frame_period_s

    def one(node: NodeData):
        if node.cube is not None:
            return process_node(node, fp, config=config, ekf=ekf, progress=progress,
                                ekf_noise=ekf_noise)
        return _from_stored_levels(node, fp, config, ekf, centroids_only=False,
                                   ekf_noise=ekf_noise, sparse=sparse, scene=scene)

    return _each_node(recording, one)


def track_recording(recording: Recording, *, ekf: EkfConfig | None = None,
                    ekf_noise: str = "data") -> tuple[Recording, dict[str, NodeReport]]:
    """Tracks of every node from its centroids only."""
    fp = recording.frame_period_s
    return _each_node(recording, lambda n: track_node(n, fp, ekf=ekf, ekf_noise=ekf_noise)
                      if n.centroids is not None else None)


def _process_stored_node(src: Path, node: NodeData, fp: float, config, ekf, centroids_only,
                         progress, ekf_noise="data", sparse=None,
                         scene=SceneConfig()) -> tuple[NodeData | None, NodeReport]:
    """One node of :func:`process_file`: its cube streamed from ``src``, else
    its stored levels. Returns the new node (None: nothing to process) and
    its report."""
    cube_meta = None
    if not centroids_only and node.radar is not None:
        try:
            cube_meta = read_cube_frames(src, node.name)
        except FileFormatError:
            cube_meta = None  # this node has no cube
    if cube_meta is None:
        out = _from_stored_levels(node, fp, config, ekf, centroids_only, ekf_noise, sparse,
                                  scene)
        if out is None:
            return None, NodeReport(name=node.name, level="none", n_frames=0, n_points=0,
                                    n_centroids=0, n_tracks=0, success=False,
                                    message="no cube, point cloud or centroids")
        return out
    radar, frames, n = cube_meta

    def frames_iter():
        for _, block in iter_cubes(src, node.name):
            yield from block

    result = process_cubes(frames_iter(), radar, config, frames=frames, progress=progress,
                           desc=f"{node.name} chain")
    tracks = track_centroids(result.centroids, _ekf_for(ekf, fp, result.centroids, ekf_noise),
                             frames=_frames_span(np.asarray(frames), ekf))
    new = dataclasses.replace(node, point_cloud=result.point_cloud, centroids=result.centroids,
                              tracks=tracks)
    return new, NodeReport(
        name=node.name, level="cube", n_frames=n, n_points=len(result.point_cloud),
        n_centroids=len(result.centroids), n_tracks=int(tracks.track_ids.size),
        success=result.success, message=result.message, chain=result)


def process_file(
    path: str | os.PathLike,
    *,
    output: str | os.PathLike | None = None,
    config: ChainConfig | None = None,
    ekf: EkfConfig | None = None,
    centroids_only: bool = False,
    progress: bool = False,
    ekf_noise: str = "data",
    sparse: bool | None = None,
    scene: SceneConfig | None = SceneConfig(),
) -> tuple[Path, dict[str, NodeReport]]:
    """Process an HDF5 recording (cubes streamed, not loaded whole) and write
    the point-cloud, centroid and track levels back.

    output : write to this path (a copy of ``path`` updated atomically);
        default: update ``path`` in place, atomically. The file's lock is
        held from reading to writing (another writer waits).
    centroids_only : ignore cubes and point clouds: only re-track from the
        stored centroids. Otherwise each node starts from its cube, else its
        point cloud, else its centroids.
    ekf_noise : the EKF's measurement noise, from each node's centroids
        (``"data"``, default) or ``ekf.measurement_std`` (``"config"``).
    sparse : clustering of stored point clouds (:func:`sparse_cluster_config`;
        None: detected per node).
    scene : the scene filters of stored point clouds (:func:`cluster_node`).
    """
    src = Path(path)
    dst = src if output is None else check_output_path(output)
    # The lock spans read -> write: another writer (mmsnap calibrate, fuse) of
    # the same file waits instead of having its update overwritten.
    with recording_lock(src):
        rec = read_recording(src, load_cubes=False)
        reports: dict[str, NodeReport] = {}
        for name, node in rec.nodes.items():
            new, reports[name] = _process_stored_node(src, node, rec.frame_period_s, config,
                                                      ekf, centroids_only, progress, ekf_noise,
                                                      sparse, scene)
            if new is not None:
                rec = rec.with_node(new)
        update_recording(src, rec, keep_cubes=True, output=None if dst.resolve() == src.resolve() else dst)
    return dst, reports
