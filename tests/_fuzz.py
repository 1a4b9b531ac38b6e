"""Settings and strategies shared by the property-based fuzz tests: only the
project's errors (:class:`mmsnap_graph.errors.MmsnapError`) may come out of a
public entry point, and a CLI run on a bad input exits 1 with one line naming
the file. Derandomized (the same examples on every run). The one-shot fusion fuzz
tests (solve with every solver, the option records) also check that
``success=True`` implies a finite state and an SPD covariance."""

from __future__ import annotations

import numpy as np
from hypothesis import HealthCheck, settings
from hypothesis import strategies as st

from factors.models import predict_measurements
from mmsnap_graph import GaussianPrior, MeasurementNoise, MmsnapError

__all__ = ["FUZZ", "CLI_FUZZ", "EDGE", "ANY_VALUE", "one_line_data_error", "FUSION_FUZZ", "FUZZ_40",
           "finite", "assert_sound", "assert_pd", "assert_rejected", "node_poses",
           "consistent_frames", "edge_frames", "PRIORS", "HUGE_DOPPLER", "SUB_FRAME_VALUES"]

FUZZ = settings(max_examples=40, deadline=None, derandomize=True, database=None,
                report_multiple_bugs=False,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much,
                                       HealthCheck.function_scoped_fixture])
CLI_FUZZ = settings(FUZZ, max_examples=12)

#: Floats a fuzzer should try: ordinary, edge and non-finite values.
EDGE = st.one_of(st.floats(-50, 50, allow_nan=False), st.sampled_from(
    [0.0, -0.0, 1e-300, -1e-300, 1e300, -1e300, np.pi, -np.pi, 4.0, np.nan, np.inf, -np.inf]))
ANY_VALUE = st.one_of(EDGE, st.integers(-10, 10), st.booleans(), st.none(), st.text(max_size=3),
                      st.lists(st.integers(0, 3), max_size=2))


def one_line_data_error(code, err, name):
    """A CLI run that failed on its data: exit 1, one line naming the file."""
    assert code == 1, err
    assert len(err) == 1 and ": error: " in err[0] and name in err[0], err

#: The fusion fuzz tests' settings: 60 derandomized examples.
FUSION_FUZZ = settings(max_examples=60, deadline=None, derandomize=True, database=None,
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



def sound_or_typed_error(call) -> None:
    """``call()`` (a fusion returning ``success``, ``state``, ``covariance``)
    either raises a project error or returns a sound result
    (:func:`assert_sound`); any other exception propagates."""
    try:
        r = call()
    except MmsnapError:
        return
    assert_sound(r.success, r.state, r.covariance)

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

#: Values a corrupted UART sub-frame field can hold (uint32): the other
#: sub-frames of TI's advanced frame, beyond its four, and any bit pattern.
SUB_FRAME_VALUES = st.one_of(st.integers(0, 3), st.sampled_from([4, 255, 2**16, 2**31, 2**32 - 1]),
                             st.integers(0, 2**32 - 1))


#: The entry-point fuzz tests' settings: 40 derandomized examples, sized for CI.
FUZZ_40 = settings(max_examples=40, deadline=None, derandomize=True, database=None,
                   report_multiple_bugs=False, suppress_health_check=list(HealthCheck))


def assert_pd(cov) -> None:
    """A finite, symmetric, positive-definite covariance (or stack of them)."""
    cov = np.asarray(cov, dtype=float)
    assert np.all(np.isfinite(cov)), cov
    np.testing.assert_allclose(cov, np.swapaxes(cov, -1, -2), rtol=1e-6, atol=1e-12)
    assert np.all(np.linalg.eigvalsh(cov) > 0), np.linalg.eigvalsh(cov)
