"""calibrate_recording's input checks (mmsnap_graph.calibration.network)."""

from __future__ import annotations

import dataclasses

import pytest

from mmsnap_graph.calibration import calibrate_recording
from mmsnap_graph.errors import CalibrationError
from mmsnap_graph.sim import simulate_recording


def test_two_nodes_with_identical_centroids_are_named():
    """One log imported as two nodes: before, a singular pose graph ("Indeterminate
    linear system") or a LinAlgError from the noise estimate."""
    rec = simulate_recording("A", "straight", levels=("centroids",), n_frames=60, seed=4)
    twin = dataclasses.replace(rec.nodes["S1"], name="S2", pose=None)
    with pytest.raises(CalibrationError, match=r"nodes S1 and S2 hold the same \d+ centroids "
                                               r"in the same frames: one log imported twice"):
        calibrate_recording(rec.with_node(twin))
