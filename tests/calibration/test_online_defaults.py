"""The live refinement's defaults: one value, shared by the library and the CLI,
importable without GTSAM."""

import subprocess
import sys

from mmsnap_graph.app.cli import build_parser
from mmsnap_graph.calibration import online, online_defaults


def test_the_refinement_and_the_cli_share_one_window():
    assert online.REFINE_WINDOW_S is online_defaults.REFINE_WINDOW_S
    assert online.REFINE_MAX_WINDOWS is online_defaults.REFINE_MAX_WINDOWS
    args = build_parser().parse_args(["live", "--calibration", "cal.json"])
    assert args.refine_window_s == online_defaults.REFINE_WINDOW_S


def test_importing_the_defaults_loads_no_gtsam():
    code = ("import sys\nimport mmsnap_graph.calibration.online_defaults\n"
            "print('gtsam' in sys.modules, 'scipy.stats' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "False"]
