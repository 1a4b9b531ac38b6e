"""``mmsnap process`` (mmsnap_graph/app/commands/process.py)."""

from mmsnap_graph.app.commands.process import HELP_DEFAULTS
from mmsnap_graph.radar.cfar import CfarConfig
from mmsnap_graph.tracking.ekf import EkfConfig


def test_the_defaults_quoted_in_the_help_are_the_configs():
    assert HELP_DEFAULTS == {"pfa": CfarConfig().pfa, "sigma_a_mps2": EkfConfig().sigma_a_mps2}
