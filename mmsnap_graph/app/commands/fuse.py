"""``mmsnap fuse``: one-shot fusion of every frame of a recording.

Writes the fused states, covariances and per-frame flags into the recording's
``/fused`` group (layout: :data:`mmsnap_graph.io.fused.FUSED_LAYOUT`), or into
a copy of the recording given by ``--output``.
"""

from __future__ import annotations

import argparse
import sys

from mmsnap_graph._atomic import check_output_path, recording_lock
from mmsnap_graph.errors import ValidationError


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "fuse",
        help="one-shot fusion of every frame (MAP or ML) into the recording's /fused group",
        description="Fuse every target in every frame of a recording with the calibrated node "
                    "poses (paper eq. 18): MAP with the paper's prior or ML, Laplace or grid "
                    "covariance. Frames that cannot be fused are flagged, not dropped.")
    p.add_argument("recording", help="HDF5 recording (docs/FORMAT.md)")
    p.add_argument("--calibration", default=None,
                   help="calibration JSON ({'nodes': {'S1': {'pose': [x_m, y_m, phi_rad]}, ...}}); "
                        "default: the poses stored in the recording")
    p.add_argument("--mode", choices=["map", "ml"], default="map",
                   help="MAP with the paper's prior, or maximum likelihood (default %(default)s)")
    p.add_argument("--covariance", choices=["laplace", "grid"], default="laplace",
                   help="Laplace (inverse information) or the paper's grid posterior "
                        "covariance (slow) (default %(default)s)")
    p.add_argument("--sigmas", nargs=3, type=float, default=None,
                   metavar=("RANGE_M", "OMEGA_RAD", "DOPPLER_MPS"),
                   help="measurement noise sigmas (default the paper's resolutions: "
                        "0.035 m, pi/4 rad, 0.1807 m/s)")
    p.add_argument("--solver", choices=["batch", "gtsam"], default="batch",
                   help="vectorized batch solver or one GTSAM graph per frame (default %(default)s)")
    p.add_argument("--source", choices=["centroids", "point_cloud"], default="centroids",
                   help="detections to fuse (default %(default)s)")
    p.add_argument("--gate", type=float, default=0.999,
                   help="association gate probability for several targets (default %(default)s)")
    p.add_argument("--grid-points", type=int, default=21,
                   help="grid points per axis for --covariance grid (default %(default)s)")
    p.add_argument("-o", "--output", default=None,
                   help="write a copy of the recording with /fused here instead of updating it")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from mmsnap_graph.app.chunked_fuse import fuse_file
    from mmsnap_graph.data.noise import MeasurementNoise
    from mmsnap_graph.io.calibration import load_calibration_poses

    if args.grid_points < 5 or args.grid_points % 2 == 0:
        raise ValidationError(f"--grid-points must be odd and >= 5, got {args.grid_points}")
    if args.output is not None:
        check_output_path(args.output)
    poses = load_calibration_poses(args.calibration) if args.calibration else None
    noise = MeasurementNoise()
    if args.sigmas is not None:
        r, w, v = args.sigmas
        noise = MeasurementNoise(range_m=r, omega_rad=w, doppler_mps=v)
    # The lock spans read -> write: a concurrent `mmsnap process` or
    # `calibrate` of the same file waits instead of being overwritten.
    with recording_lock(args.recording):
        # Read, fused and written window by window (long recordings, issue 13).
        fused = fuse_file(args.recording, output=args.output, node_poses=poses, mode=args.mode,
                               covariance=args.covariance, noise=noise, solver=args.solver,
                               source=args.source, gate_probability=args.gate,
                               grid_points_per_axis=args.grid_points,
                               progress=False if args.no_progress else None)
    n_ok, path, frames = fused.n_success, fused.path, fused.n_frames
    print(f"fused {fused.n_rows} targets in {frames} frames ({args.mode}, {args.covariance}, "
          f"{args.solver}): {n_ok} succeeded, {fused.n_rows - n_ok} flagged; wrote {path}:/fused",
          file=sys.stdout)
    return 0
