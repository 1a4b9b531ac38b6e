"""Hypothesis strategies and checks shared by the fuzz tests of one-shot
fusion (fuse_frame in tests/fusion/solvers/test_gtsam_graph.py, fuse_batch in
test_vectorized.py, the option records in tests/fusion/test_options.py).

Properties: the solvers raise only the project's errors
(:class:`mmsnap_graph.MmsnapError`), and ``success=True`` implies a finite
state and a symmetric positive-definite covariance. Examples are
derandomized (the same in every run).
"""

from __future__ import annotations

import numpy as np
from hypothesis import HealthCheck, settings
from hypothesis import strategies as st

from factors.models import predict_measurements
from mmsnap_graph import GaussianPrior, MeasurementNoise, MmsnapError


FUZZ = settings(max_examples=60, deadline=None, derandomize=True, database=None,
                report_multiple_bugs=False,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])


def finite(lo: float, hi: float):
    return st.floats(lo, hi, allow_nan=False, allow_infinity=False)


def assert_sound(success, state, covariance) -> None:
    """success=True implies a finite state and an SPD covariance."""
    success = np.atleast_1d(np.asarray(success))
    state = np.asarray(state, dtype=float).reshape(-1, 4)
    cov = np.asarray(covariance, dtype=float).reshape(-1, 4, 4)
    for i in np.flatnonzero(success):
        assert np.all(np.isfinite(state[i])), f"success with state {state[i]}"
        assert np.all(np.isfinite(cov[i])), f"success with covariance {cov[i]}"
        np.testing.assert_allclose(cov[i], cov[i].T, rtol=1e-9, atol=0)
        assert np.linalg.eigvalsh(cov[i]).min() > 0, f"success with covariance {cov[i]}"


@st.composite
def node_poses(draw, n_min: int = 1, n_max: int = 4):
    n = draw(st.integers(n_min, n_max))
    return np.array([[draw(finite(-20, 20)), draw(finite(-20, 20)), draw(finite(-np.pi, np.pi))]
                     for _ in range(n)])


@st.composite
def consistent_frames(draw):
    """Measurements predicted from a target at least 0.5 m from every node,
    plus noise of the given sigmas (the domain a radar produces)."""
    poses = draw(node_poses(2, 4))
    state = np.array([draw(finite(-15, 15)), draw(finite(-15, 15)),
                      draw(finite(-5, 5)), draw(finite(-5, 5))])
    if np.min(np.hypot(poses[:, 0] - state[0], poses[:, 1] - state[1])) < 0.5:
        state[:2] = poses[0, :2] + 3.0  # keep the target off the nodes
    noise = MeasurementNoise(range_m=draw(finite(1e-3, 1.0)), omega_rad=draw(finite(1e-3, 1.0)),
                             doppler_mps=draw(finite(1e-3, 1.0)))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    z = predict_measurements(state, poses)
    z = z + rng.standard_normal(z.shape) * [noise.range_m, noise.omega_rad, noise.doppler_mps]
    z[:, 0] = np.abs(z[:, 0]) + 1e-3
    z[:, 1] = np.clip(z[:, 1], -np.pi, np.pi)
    observed = np.array([draw(st.booleans()) for _ in range(len(poses))])
    observed[draw(st.integers(0, len(poses) - 1))] = True
    return poses, z, observed, noise


@st.composite
def edge_frames(draw, sigmas=finite(1e-6, 1e6)):
    """Any in-range measurement: range 0, tiny or large, omega at 0 or +-pi,
    large Doppler, and sigmas within ``sigmas``."""
    poses = draw(node_poses())
    ranges = st.one_of(st.sampled_from([0.0, 1e-300, 1e-9]), finite(0, 50))
    omegas = st.one_of(st.sampled_from([0.0, np.pi, -np.pi]), finite(-np.pi, np.pi))
    dopplers = st.one_of(st.sampled_from([0.0, -30.0, 30.0]), finite(-10, 10))
    z = np.array([[draw(ranges), draw(omegas), draw(dopplers)] for _ in range(len(poses))])
    noise = MeasurementNoise(range_m=draw(sigmas), omega_rad=draw(sigmas), doppler_mps=draw(sigmas))
    return poses, z, noise


PRIORS = st.sampled_from([GaussianPrior(), None])


def assert_rejected(fn, **kwargs) -> None:
    """``fn(**kwargs)`` must raise a project error (anything else propagates)."""
    try:
        fn(**kwargs)
    except MmsnapError:
        return
    raise AssertionError(f"accepted {kwargs}")


HUGE_DOPPLER = st.sampled_from([1e16, -3e16, 1e100, -1e300])
