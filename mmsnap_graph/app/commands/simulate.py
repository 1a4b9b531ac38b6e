"""``mmsnap simulate``: write a simulated recording (docs/SIMULATOR.md)."""

from __future__ import annotations

import argparse
import contextlib
import math
import sys

from mmsnap_graph._atomic import check_output_path, scratch_folder
from mmsnap_graph.errors import ValidationError

from .arguments import HEADING_HELP, named_pose


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "simulate",
        help="simulate a recording (truth, centroids, point clouds, raw ADC cubes)",
        description="Simulate walking humans seen by a radar network and write an HDF5 "
                    "recording (docs/FORMAT.md) with the ground truth. Networks A, B, C are "
                    "the paper's configurations (docs/SIMULATOR.md); --node gives any other.")
    p.add_argument("-c", "--configuration", choices=["A", "B", "C"], default="C",
                   help="network configuration (default %(default)s); ignored with --node")
    p.add_argument("--node", action="append", type=named_pose, metavar="NAME=X,Y,PHI_DEG",
                   help="a node pose: x, y in metres; repeat, the first is the reference "
                        f"S1, e.g. S1=0,0,0. {HEADING_HELP}, stored in radians")
    p.add_argument("-t", "--trajectory", choices=["straight", "random"], default="straight",
                   help="target trajectory (default %(default)s)")
    p.add_argument("-l", "--levels", default="centroids,point_cloud",
                   help="comma-separated levels among centroids, point_cloud, cube "
                        "(default %(default)s; a raw cube is 5.9 MB per node and frame)")
    p.add_argument("--model", choices=["real", "clean"], default="real",
                   help="real: the physics of real TI point clouds (near-side reflection, "
                        "correlated centroid errors, static scene, multipath ghosts, split "
                        "clusters, sparse clouds, float16 values; docs/SIMULATOR.md); clean: a "
                        "point target with independent Gaussian errors (default %(default)s)")
    p.add_argument("-n", "--frames", type=int, default=600,
                   help="number of frames (default %(default)s = 90 s at 150 ms)")
    p.add_argument("--cube-frames", type=int, default=None,
                   help="raw cubes only for the first N frames (default: every frame)")
    p.add_argument("--frame-period", type=float, default=None,
                   help="frame period in seconds (default: the radar's, 0.15)")
    p.add_argument("--targets", type=int, default=1, help="number of targets (default 1)")
    p.add_argument("-s", "--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--known-poses", action="store_true",
                   help="store the true node poses as the nodes' poses (calibrated network)")
    p.add_argument("-o", "--output", required=True, help="output HDF5 file")
    p.add_argument("--overwrite", action="store_true", help="replace an existing output file")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def simulation_options(args: argparse.Namespace):
    """The :class:`~mmsnap_graph.sim.SimulationOptions` of the command line."""
    from mmsnap_graph.sim import RealPhysics, SimulationOptions

    return SimulationOptions(physics=RealPhysics() if args.model == "real" else None,
                             frame_period_s=args.frame_period, n_targets=args.targets,
                             cube_frames=args.cube_frames, known_poses=args.known_poses)


def cube_megabytes(options, n_nodes: int, n_frames: int) -> float:
    """Size of the raw cubes in MB (complex64 in memory and in the file
    before compression)."""
    n_cube = n_frames if options.cube_frames is None else min(int(options.cube_frames), n_frames)
    return n_nodes * n_cube * math.prod(options.radar.cube_shape) * 8 / 1e6


def run(args: argparse.Namespace) -> int:
    # Imported here: h5py and the simulator stay off `mmsnap --help`.
    from tqdm import tqdm

    from mmsnap_graph.io import write_recording
    from mmsnap_graph.sim import network_poses, simulate_recording

    levels = tuple(v.strip() for v in args.levels.split(",") if v.strip())
    network = dict(args.node) if args.node else args.configuration
    if args.node and len(network) != len(args.node):
        raise ValidationError("--node names must be distinct")
    if args.frames < 1:
        raise ValidationError(f"--frames {args.frames} must be >= 1")
    options = simulation_options(args)
    out = check_output_path(args.output)
    if out.exists() and not args.overwrite:
        raise ValidationError(f"{out} exists; pass --overwrite to replace it")
    progress = not args.no_progress and sys.stderr.isatty()
    bar = None
    # Cubes of long recordings go to memory-mapped scratch files next to the
    # output (2 nodes x 600 frames of Table I cubes are 3.5 GB), in a folder
    # that the next write of the output removes if a kill -9 left it.
    with contextlib.ExitStack() as stack:
        tmpdir = stack.enter_context(scratch_folder(out)) if "cube" in levels else None
        if "cube" in levels:
            n_nodes = len(network_poses(network))
            mb = cube_megabytes(options, n_nodes, args.frames)
            n_cube = mb * 1e6 / (n_nodes * math.prod(options.radar.cube_shape) * 8)
            print(f"raw ADC cubes: {n_nodes} nodes x {n_cube:.0f} frames = {mb:,.0f} MB "
                  f"to synthesize and write (gzip makes the file smaller; --cube-frames N "
                  f"limits them)", file=sys.stderr)
        rec = simulate_recording(network, args.trajectory, options, levels=levels,
                                 n_frames=args.frames, seed=args.seed, progress=progress,
                                 cube_memmap_dir=tmpdir)
        if progress and "cube" in levels:
            total = sum(node.cube.shape[0] for node in rec.nodes.values())
            bar = tqdm(total=total, unit="frame", desc="writing raw ADC cubes")
        if bar is not None:
            stack.callback(bar.close)
        write_recording(out, rec, overwrite=args.overwrite,
                        progress=None if bar is None else bar.update)
    for name, node in rec.nodes.items():
        parts = []
        for level, noun in (("centroids", "centroids"), ("point_cloud", "points")):
            det = getattr(node, level)
            if det is not None:
                other = int((det.target_id < 0).sum()) if det.target_id is not None else 0
                parts.append(f"{len(det)} {noun}" + (
                    f" ({other} not of a person: static scene, mirror images, split halves, "
                    "false alarms)" if other else ""))
        if node.cube is not None:
            parts.append(f"{node.cube.shape[0]} cubes")
        print(f"{name}: " + ", ".join(parts))
    print(f"wrote {out} ({rec.metadata['network']}, {rec.metadata['trajectory']}, "
          f"{args.frames} frames, seed {args.seed}, {args.model} model)")
    return 0
