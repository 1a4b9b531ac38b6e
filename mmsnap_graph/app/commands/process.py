"""``mmsnap process RECORDING``: fill a recording's point-cloud, centroid and
track levels from its raw ADC cubes (or its tracks from its centroids)."""

from __future__ import annotations

import argparse
import dataclasses
import sys

import numpy as np

from mmsnap_graph._atomic import check_output_path
from mmsnap_graph.app.commands.file_rules import add_overwrite
from mmsnap_graph.data.body import SCENE_MERGE_RADIUS_M
from mmsnap_graph.errors import ConfigurationError, ValidationError

#: Defaults quoted in the help: ``CfarConfig().pfa`` and
#: ``EkfConfig().sigma_a_mps2``, written out so that building the parser
#: (``mmsnap --help``) does not import the signal chain, SciPy and
#: scikit-learn (a test keeps them equal).
HELP_DEFAULTS = {"pfa": 1e-6, "sigma_a_mps2": 3.0}


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "process",
        help="run the per-node signal chain (cube -> point cloud -> centroids -> EKF tracks)",
        description="Run each node's signal chain on a recording: range/Doppler/angle FFTs, "
                    "static clutter removal, 2D OS-CFAR, torso DBSCAN centroids and a local "
                    "EKF. Nodes without a cube start from their point cloud (torso DBSCAN, EKF), else are re-tracked from their centroids. The file "
                    "is updated atomically (or written to --output).")
    p.add_argument("recording", nargs="?", default=None,
                   help="HDF5 recording (docs/FORMAT.md); not needed with --show-config")
    p.add_argument("-o", "--output", help="write the result here instead of updating in place")
    p.add_argument("--centroids-only", action="store_true",
                   help="ignore cubes and point clouds: only build tracks from the stored centroids")
    p.add_argument("--config", metavar="FILE", default=None,
                   help="TOML file with every chain, clustering and EKF option (tables [chain], "
                        "[chain.cfar], [chain.cluster], [ekf], [scene]; a [matching] table, mmsnap "
                        "calibrate's, is ignored; see --show-config and docs/TI.md)")
    p.add_argument("--show-config", action="store_true",
                   help="print the effective configuration (defaults, --config, options) as "
                        "TOML and exit")
    p.add_argument("--pfa", type=float, default=None,
                   help=f"OS-CFAR false-alarm probability per cell; overrides the file "
                        f"(default {HELP_DEFAULTS['pfa']:g})")
    p.add_argument("--sigma-a", type=float, default=None,
                   help=f"EKF white-acceleration std, m/s^2; overrides the file "
                        f"(default {HELP_DEFAULTS['sigma_a_mps2']:g})")
    p.add_argument("--sparse", choices=["auto", "on", "off"], default=None,
                   help="cluster stored point clouds as sparse (DBSCAN min_samples=1: a "
                        "person's 2-3 points are a centroid): when the median non-empty frame "
                        "holds fewer than 6 points after the scene filters (auto), always (on) "
                        "or never (off); "
                        "overrides the file's [chain.cluster] sparse (default auto)")
    p.add_argument("--no-static-scene", action="store_true",
                   help="stored point clouds: keep zero-Doppler points of the static scene "
                        "(default: dropped where a background map learned over the recording "
                        "finds them; docs/TI.md)")
    p.add_argument("--no-body-merge", action="store_true",
                   help="stored point clouds: do not merge a node's centroids of a frame "
                        f"closer than the merge radius ([scene] body_m, default "
                        f"{SCENE_MERGE_RADIUS_M:g} m)")
    p.add_argument("--no-ghost-filter", action="store_true",
                   help="stored point clouds: keep multipath ghosts (a weaker centroid further "
                        "along the same bearing with a consistent Doppler)")
    p.add_argument("--no-existence-check", action="store_true",
                   help="stored point clouds: keep centroids that no neighbouring frame "
                        "confirms (one-frame blips)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_overwrite(p)
    p.set_defaults(func=run)


def effective_config(args: argparse.Namespace):
    """Defaults, then the ``--config`` file, then the explicit options: a
    :class:`~mmsnap_graph.app.config_file.ProcessConfig`."""
    from mmsnap_graph.app.config_file import SPARSE_VALUES, ProcessConfig, read_process_config

    cfg = ProcessConfig() if args.config is None else read_process_config(args.config)
    chain, ekf = cfg.chain, cfg.ekf
    try:
        if args.pfa is not None:
            chain = dataclasses.replace(chain, cfar=dataclasses.replace(chain.cfar, pfa=args.pfa))
        if args.sigma_a is not None:
            ekf = dataclasses.replace(ekf, sigma_a_mps2=args.sigma_a)
    except (TypeError, ValueError) as exc:
        raise ConfigurationError(f"mmsnap process option: {exc}") from None
    sparse = cfg.sparse if args.sparse is None else SPARSE_VALUES[args.sparse]
    scene = dataclasses.replace(
        cfg.scene, static=cfg.scene.static and not args.no_static_scene,
        merge=cfg.scene.merge and not args.no_body_merge,
        ghosts=cfg.scene.ghosts and not args.no_ghost_filter,
        existence=cfg.scene.existence and not args.no_existence_check)
    return ProcessConfig(chain=chain, ekf=ekf, ekf_noise_from_data=cfg.ekf_noise_from_data,
                         sparse=sparse, scene=scene)


def counts_text(node, frame_period_s: float) -> str:
    """What a node's centroid and track counts mean, in words: centroids are
    the clusters kept per frame (a person, or clutter and ghosts the scene
    filters let through); tracks are the EKF's confirmed track ids, a new id
    each time a track is lost (no centroid in its gate for ``max_coast_s``)
    and restarted, so one walker can make many tracks one after another."""
    lines = []
    cents, tracks = node.centroids, node.tracks
    if cents is not None and len(cents):
        frames, per_frame = np.unique(cents.frame, return_counts=True)
        lines.append(f"  centroids: {len(cents)} clusters in {frames.size} frames (one a frame "
                     f"is one person; at most {per_frame.max()} in a frame, "
                     f"{int(np.sum(per_frame > 1))} frames with more: clutter, ghosts or "
                     f"several people)")
    if tracks is not None and tracks.frame.size:
        ids, lengths = np.unique(tracks.track_id, return_counts=True)
        t_frames, alive = np.unique(tracks.frame, return_counts=True)
        longest = int(lengths.max())
        lines.append(f"  tracks: {ids.size} confirmed EKF track ids (a lost track ends and a "
                     f"new id starts: one walker gives several, one after another)")
        lines.append(f"  tracks alive in {t_frames.size} frames, at most {alive.max()} at once; "
                     f"longest {longest} frames ({longest * frame_period_s:.1f} s), median "
                     f"{int(np.median(lengths))} frames")
    return "\n".join(lines) if lines else "  no centroids, no tracks"


def run(args: argparse.Namespace) -> int:
    from mmsnap_graph.app.config_file import process_config_to_toml

    cfg = effective_config(args)
    if args.show_config:
        sys.stdout.write(process_config_to_toml(cfg))
        return 0
    if args.recording is None:
        raise ValidationError("mmsnap process: a recording is required (unless --show-config)")
    from ..pipeline import process_file  # here: `mmsnap --help` does not import h5py
    if args.output is not None:
        check_output_path(args.output)

    config, ekf = cfg.chain, cfg.ekf
    progress = not args.no_progress and sys.stderr.isatty()
    path, reports = process_file(args.recording, output=args.output, config=config, ekf=ekf,
                                 centroids_only=args.centroids_only, progress=progress,
                                 ekf_noise="data" if cfg.ekf_noise_from_data else "config",
                                 sparse=cfg.sparse, scene=cfg.scene)
    from mmsnap_graph.io import read_recording

    rec = read_recording(path, load_cubes=False)
    for rep in reports.values():
        print(f"{rep.name}: {rep.level}: {rep.n_points} points, {rep.n_centroids} centroids, "
              f"{rep.n_tracks} tracks ({rep.message})")
        node = rec.nodes.get(rep.name)
        if node is not None:
            print(counts_text(node, rec.frame_period_s))
    print(f"wrote {path}")
    # Flagged frames are reported above; failing is for nothing processed.
    return 0 if any(rep.level != "none" for rep in reports.values()) else 1
