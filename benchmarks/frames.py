"""Shared pieces of the fusion benchmarks: seeded two-node frames in a
configuration's common area, and the scipy ``least_squares`` baseline that
every fusion speed figure is compared with."""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares

from factors.models import measurement_model, residual, wrap_angle
from mmsnap_graph.sim.scenes import COMMON_AREA_CENTERS, PAPER_CONFIGURATIONS
from mmsnap_graph.data.noise import MeasurementNoise
from mmsnap_graph.fusion.frame_problem import FrameProblem, initial_states

#: (N, 3) node poses of each paper configuration.
POSES = {name: np.stack([p["S1"], p["S2"]]) for name, p in PAPER_CONFIGURATIONS.items()}


def simulate(configuration: str, n_frames: int, seed: int, *, half_width_m: float = 1.5):
    """Random states within ``half_width_m`` of the configuration's common-area
    centre, velocities ~N(0, 1) m/s, and measurements with the paper's noise.
    Returns states (F, 4) and measurements (F, N, 3)."""
    rng = np.random.default_rng(seed)
    centre = COMMON_AREA_CENTERS[configuration]
    states = np.column_stack([
        centre[0] + rng.uniform(-half_width_m, half_width_m, n_frames),
        centre[1] + rng.uniform(-half_width_m, half_width_m, n_frames),
        rng.normal(0.0, 1.0, n_frames),
        rng.normal(0.0, 1.0, n_frames),
    ])
    h, _ = measurement_model(states[:, None, :], POSES[configuration])
    z = h + rng.normal(size=h.shape) * MeasurementNoise().sigmas
    z[..., 1] = wrap_angle(z[..., 1])
    return states, z


def scipy_fuse(poses, z, noise, prior):
    """The baseline: MAP by scipy ``least_squares`` (LM, tight tolerances) from
    the same initial value, covariance ``(J^T J)^-1`` from its Jacobian."""
    sig = noise.sigmas
    inv_prior = 1.0 / prior.sigmas

    def fun(x):
        h, _ = measurement_model(x, poses)
        return np.concatenate([(residual(h, z) / sig).ravel(), (x - prior.mean) * inv_prior])

    def jac(x):
        _, j = measurement_model(x, poses)
        return np.vstack([(j / sig[:, None]).reshape(-1, 4), np.diag(inv_prior)])

    # One frame, validated, its initial value in plain floats: what a per-frame
    # caller (and the per-frame GTSAM solver) computes, not the numpy batch form.
    x0 = initial_states(FrameProblem(poses=poses, measurements=z, prior=prior, noise=noise),
                        per_frame=True)[0]
    sol = least_squares(fun, x0, jac=jac, method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15)
    return sol.x, np.linalg.inv(sol.jac.T @ sol.jac)
