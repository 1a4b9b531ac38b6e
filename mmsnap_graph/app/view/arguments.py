"""The view's command-line options, one place for ``mmsnap live`` and
``mmsnap replay``: ``--view`` (serve the fused people live to Foxglove or
Lichtblick), ``--view-log FILE.mcap`` (write them to an MCAP file),
``--view-port``, ``--view-history``."""

from __future__ import annotations

import argparse
import sys

__all__ = ["add_view_options", "view_sink"]


def add_view_options(p: argparse.ArgumentParser) -> None:
    from .foxglove_log import DEFAULT_PORT

    g = p.add_argument_group("view (Foxglove / Lichtblick; pip install \".[view]\")")
    g.add_argument("--view", action="store_true",
                   help="serve each board's points, the radars' fields of view and the fused "
                        "people (2-sigma ellipses, velocity arrows, ids, track histories) on a "
                        f"WebSocket: connect Foxglove or Lichtblick to ws://127.0.0.1:PORT "
                        "(docs/how-to/view.md)")
    g.add_argument("--view-log", default=None, metavar="FILE.mcap",
                   help="write the same view to an MCAP file (open it in Foxglove or "
                        "Lichtblick); replaced only with --overwrite")
    g.add_argument("--view-port", type=int, default=DEFAULT_PORT, metavar="PORT",
                   help="the WebSocket port of --view (default %(default)s; 0: any free port)")
    g.add_argument("--view-history", type=float, default=10.0, metavar="SECONDS",
                   help="seconds of each person's track drawn (default %(default)s)")


def view_sink(args: argparse.Namespace, names, poses, *, time_origin_s: float = 0.0):
    """The :class:`~.foxglove_log.FoxgloveView` the options ask for, or None;
    the server's address is said on stderr."""
    if not (args.view or args.view_log):
        return None
    from .foxglove_log import FoxgloveView, ViewOptions

    options = ViewOptions(log_path=args.view_log, overwrite=args.overwrite, serve=args.view,
                          port=args.view_port, history_s=args.view_history,
                          time_origin_s=time_origin_s)
    view = FoxgloveView(names, poses, options)
    if view.url is not None:
        print(f"view: open Foxglove or Lichtblick, connect to {view.url} (Foxglove WebSocket)",
              file=sys.stderr)
    return view
