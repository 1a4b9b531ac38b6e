"""Recordings shared by the calibration tests.

``three_node_recording(seed, with_tracks=False)`` is the network
:data:`_shared.NETWORK_3` with one random walker, 300 frames of centroids at
150 ms (and, with ``with_tracks``, each node's EKF tracks of its centroids):
built once per (seed, with_tracks) and session, so a test must not change one
in place.
"""

from __future__ import annotations

import dataclasses
import functools

import pytest

from mmsnap_graph.sim import CLEAN, simulate_recording
from mmsnap_graph.tracking.ekf import EkfConfig, track_centroids

from _shared import NETWORK_3


@functools.cache
def _three_node_recording(seed: int, with_tracks: bool = False):
    rec = simulate_recording(NETWORK_3, "random", CLEAN, levels=("centroids",), n_frames=300,
                             seed=seed)
    if with_tracks:
        cfg = EkfConfig(frame_period_s=rec.frame_period_s)
        rec = dataclasses.replace(rec, nodes={
            n: dataclasses.replace(node, tracks=track_centroids(node.centroids, cfg))
            for n, node in rec.nodes.items()})
    return rec


@pytest.fixture(scope="session")
def three_node_recording():
    """The builder of the three-node recordings (module doc)."""
    return _three_node_recording
