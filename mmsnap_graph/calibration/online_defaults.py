"""The live refinement's defaults (:class:`~mmsnap_graph.calibration.online.OnlineRefinement`).

A module of constants only, so that ``mmsnap live --help`` shows them
without importing GTSAM or SciPy's optimisers.
"""

from __future__ import annotations

__all__ = ["REFINE_WINDOW_S", "REFINE_MAX_WINDOWS"]

#: The live refinement's window (s): a minute of walking calibrates a room
#: (docs/LIVE.md), and one window of 4 boards is about a second of CPU.
REFINE_WINDOW_S = 60.0
#: Windows combined (the last hour at the default window).
REFINE_MAX_WINDOWS = 60
