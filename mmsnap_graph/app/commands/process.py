"""``mmsnap process RECORDING``: fill a recording's point-cloud, centroid and
track levels from its raw ADC cubes (or its tracks from its centroids)."""

from __future__ import annotations

import argparse
import dataclasses
import sys

from mmsnap_graph._atomic import check_output_path
from mmsnap_graph.radar.cfar import CfarConfig
from mmsnap_graph.radar.chain import ChainConfig
from mmsnap_graph.tracking.ekf import EkfConfig


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "process",
        help="run the per-node signal chain (cube -> point cloud -> centroids -> EKF tracks)",
        description="Run each node's signal chain on a recording: range/Doppler/angle FFTs, "
                    "static clutter removal, 2D OS-CFAR, torso DBSCAN centroids and a local "
                    "EKF. Nodes without a cube start from their point cloud (torso DBSCAN, EKF), else are re-tracked from their centroids. The file "
                    "is updated atomically (or written to --output).")
    p.add_argument("recording", help="HDF5 recording (docs/FORMAT.md)")
    p.add_argument("-o", "--output", help="write the result here instead of updating in place")
    p.add_argument("--centroids-only", action="store_true",
                   help="ignore cubes and point clouds: only build tracks from the stored centroids")
    p.add_argument("--pfa", type=float, default=CfarConfig().pfa,
                   help="OS-CFAR false-alarm probability per cell (default %(default)g)")
    p.add_argument("--sigma-a", type=float, default=EkfConfig().sigma_a_mps2,
                   help="EKF white-acceleration std, m/s^2 (default %(default)g)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..pipeline import process_file  # here: `mmsnap --help` does not import h5py
    if args.output is not None:
        check_output_path(args.output)

    config = ChainConfig(cfar=dataclasses.replace(CfarConfig(), pfa=args.pfa))
    ekf = EkfConfig(sigma_a_mps2=args.sigma_a)
    progress = not args.no_progress and sys.stderr.isatty()
    path, reports = process_file(args.recording, output=args.output, config=config, ekf=ekf,
                                 centroids_only=args.centroids_only, progress=progress)
    for rep in reports.values():
        print(f"{rep.name}: {rep.level}: {rep.n_points} points, {rep.n_centroids} centroids, "
              f"{rep.n_tracks} tracks ({rep.message})")
    print(f"wrote {path}")
    # Flagged frames are reported above; failing is for nothing processed.
    return 0 if any(rep.level != "none" for rep in reports.values()) else 1
