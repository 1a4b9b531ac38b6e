"""``mmsnap plot``: a recording as a figure (PNG or SVG) for the user
without a viewer: the room, the radars with their fields of view, the
points and the fused people with their 2-sigma ellipses and ids
(:mod:`mmsnap_graph.app.view.plot`, docs/how-to/view.md)."""

from __future__ import annotations

import argparse

from ..file_rules import add_overwrite


def _pair(text: str) -> tuple[int, int]:
    try:
        first, last = (int(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--frames {text!r} must look like FIRST,LAST "
                                         "(frame numbers)") from None
    return first, last


def register(subparsers) -> None:
    from mmsnap_graph.app.commands.arguments import bounds_value

    p = subparsers.add_parser(
        "plot", help="a recording as a figure: room, radars, points, fused people with ids",
        description="Draw a recording (real or simulated) in the reference radar's frame: the "
                    "room (--bounds), each radar "
                    "with its boresight and field of view, its points, and the fused people "
                    "(/fused, from mmsnap fuse): each person id's path, 2-sigma position "
                    "ellipses and id. PNG or SVG, from the -o suffix.")
    p.add_argument("recording", help="HDF5 recording (docs/FORMAT.md)")
    p.add_argument("-o", "--output", required=True, help="the figure: FILE.png or FILE.svg")
    p.add_argument("--bounds", type=bounds_value, default=None, metavar="XMIN,XMAX,YMIN,YMAX",
                   help="the room's box in metres, in the reference frame (as mmsnap fuse "
                        "--bounds); default: not drawn")
    p.add_argument("--frames", type=_pair, default=None, metavar="FIRST,LAST",
                   help="draw these frames only (default: all)")
    p.add_argument("--source", choices=["auto", "point_cloud", "centroids"], default="auto",
                   help="the points drawn: the point cloud when there is one (auto), or the "
                        "centroids")
    p.add_argument("--ellipse-every", type=float, default=1.0, metavar="SECONDS",
                   help="seconds between two ellipses of one person (default %(default)s)")
    p.add_argument("--fov-range", type=float, default=None, metavar="METRES",
                   help="range the fields of view are drawn to (default: the farthest point)")
    p.add_argument("--dpi", type=int, default=150, help="resolution of a PNG (default "
                                                         "%(default)s, 100 to 600)")
    add_overwrite(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from mmsnap_graph.app.view.plot import PlotOptions, check_output, plot_recording, save_plot

    check_output(args.output)  # before the work: a .pdf name is refused at once
    options = PlotOptions(bounds=args.bounds, frames=args.frames, source=args.source,
                          ellipse_every_s=args.ellipse_every, fov_range_m=args.fov_range,
                          dpi=args.dpi)
    path = save_plot(plot_recording(args.recording, options), args.output, dpi=options.dpi)
    print(f"wrote {path}")
    return 0
