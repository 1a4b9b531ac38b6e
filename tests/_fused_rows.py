"""Synthetic fused rows for the room-frame checks' tests."""

from __future__ import annotations

import numpy as np

from mmsnap_graph.data.results import FusedSequence


def fused_rows(frame, xy, *, nodes=None, velocity=None, sigma_m=0.03, cost=None):
    """K successful rows at ``xy`` (K, 2), seen by ``nodes`` (K,) of 2 nodes."""
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    k = xy.shape[0]
    nodes = np.full(k, 2) if nodes is None else np.asarray(nodes)
    observed = np.zeros((k, 2), bool)
    observed[:, 0] = True
    observed[:, 1] = nodes >= 2
    vel = np.full((k, 2), 0.8) if velocity is None else np.asarray(velocity, float).reshape(-1, 2)
    cov = np.tile(np.eye(4) * sigma_m**2, (k, 1, 1))
    return FusedSequence(
        node_names=("S1", "S2"), node_poses=np.array([[0, 0, 0], [1.7, 1.65, np.pi / 2]]),
        mode="ml", covariance_method="laplace", solver="vectorized", frame=np.asarray(frame),
        target=np.zeros(k, int), label=np.full(k, -1), detection_index=np.where(observed, 0, -1),
        observed=observed, state=np.c_[xy, vel], covariance=cov, laplace_covariance=cov,
        success=np.ones(k, bool), status=np.zeros(k, np.int8),
        message=np.array(["converged"] * k, dtype=object), iterations=np.ones(k, int),
        final_cost=np.zeros(k) if cost is None else np.asarray(cost, float),
        degeneracy=np.ones(k), noise_sigmas=np.array([0.05, 0.1, 0.2]), prior_mean=None,
        prior_sigmas=None, gate_probability=0.999)
