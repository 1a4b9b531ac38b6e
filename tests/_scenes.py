"""Small synthetic calibration scenes shared by several test modules."""

from __future__ import annotations

import numpy as np

from factors.models import measurement_model

__all__ = ["depth_scene"]


def depth_scene(sigmas, seed: int = 0, n: int = 60, depth: float = 0.07):
    """Three nodes seeing a target on a smooth walk, every range ``depth``
    short (a body's reflection depth), noise ``sigmas`` (range_m, omega_rad,
    doppler_mps). Returns ``(poses, states, measurements)``."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.15
    states = np.column_stack([1.5 * np.sin(0.3 * t), 3.5 + np.cos(0.4 * t),
                              0.45 * np.cos(0.3 * t), -0.4 * np.sin(0.4 * t)])
    poses = {"S1": np.zeros(3), "S2": np.array([4.0, 4.0, np.pi / 2]),
             "S3": np.array([0.5, 7.5, np.pi])}
    meas = {}
    for name, pose in poses.items():
        h, _ = measurement_model(states, pose)
        h[:, 0] -= depth
        meas[name] = h + rng.normal(0.0, sigmas, (n, 3))
    return poses, states, meas
