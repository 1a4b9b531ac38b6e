"""The frame problem as a value (issue 26, item 1): validated once when made,
batched over frames, sliced without validating again; its one initial state
(the plain-float path of small problems equal to the vectorized one)."""

from __future__ import annotations

import numpy as np
import pytest

from _shared import PAPER_NOISE, PAPER_PRIOR, POSES_BC
from factors.models import predict_measurements, wrap_angle
from mmsnap_graph import MeasurementNoise
from mmsnap_graph.errors import GeometryError, ValidationError
from mmsnap_graph.fusion import frame_problem as fp
from mmsnap_graph.fusion.frame_problem import FrameProblem, initial_states, whitened_residuals

NOISES = (PAPER_NOISE, MeasurementNoise(range_m=0.05, omega_rad=0.5, doppler_mps=0.15),
          MeasurementNoise(range_m=0.03, omega_rad=0.9, doppler_mps=0.2))


def _z(n_frames=30, seed=0):
    rng = np.random.default_rng(seed)
    truth = np.column_stack([rng.uniform(-1, 1, n_frames), rng.uniform(2, 4, n_frames),
                             rng.normal(0, 0.7, (n_frames, 2))])
    z = np.stack([predict_measurements(t, POSES_BC) for t in truth])
    z += rng.normal(size=z.shape) * PAPER_NOISE.sigmas
    z[..., 1] = wrap_angle(z[..., 1])
    obs = rng.random(z.shape[:2]) > 0.3
    return z, obs


def test_a_problem_is_validated_once_and_its_slices_share_it(monkeypatch):
    z, obs = _z()
    calls = []
    real = fp.check_node_noise
    monkeypatch.setattr(fp, "check_node_noise", lambda *a: calls.append(1) or real(*a))
    problem = FrameProblem(poses=POSES_BC, measurements=z, observed=obs, noise=NOISES)
    sub = problem[3:7].with_observed(obs[3:7] & ~np.eye(4, 3, dtype=bool)).with_initial_state(
        np.zeros((4, 4)) + [0.0, 3.0, 0.0, 0.0])
    other = problem.with_frames(z[:2], obs[:2])
    assert calls == [1]
    assert len(problem) == 30 and len(sub) == 4 and problem[5].n_frames == 1
    assert sub.noise is problem.noise and other.noise is problem.noise
    assert not problem.measurements.flags.writeable and not problem.observed.flags.writeable
    assert np.all(problem.measurements[~obs] == 0.0)  # unobserved rows are zeros
    # The masks only remove nodes.
    assert not (sub.observed & ~obs[3:7]).any()


def test_one_frame_and_the_nan_convention():
    z, _ = _z(1)
    z[0, 1] = np.nan
    problem = FrameProblem(poses=POSES_BC, measurements=z[0])
    assert problem.n_frames == 1 and problem.observed.tolist() == [[True, False, True]]


@pytest.mark.parametrize("observed", [None, "mask", "all"])
def test_one_frame_is_the_batch_of_that_frame_in_its_own_read_only_copies(observed):
    """The one-frame path (an (N, 3) frame) stores exactly what the batch path
    stores for the same frame as (1, N, 3), in arrays of its own."""
    z, _ = _z(1, seed=3)
    frame = z[0].copy()
    seen = np.array([True, observed == "all", True])
    frame[~seen] = np.nan
    mask = None if observed is None else seen.copy()
    one = FrameProblem(poses=POSES_BC, measurements=frame, observed=mask)
    batch = FrameProblem(poses=POSES_BC, measurements=frame[None],
                         observed=None if mask is None else mask[None])
    for name in ("poses", "measurements", "observed"):
        a, b = getattr(one, name), getattr(batch, name)
        assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()
        assert not a.flags.writeable
    before = one.measurements.copy()
    frame[:] = 7.0  # the caller's arrays are not the problem's
    if mask is not None:
        mask[:] = False
    assert one.measurements.tobytes() == before.tobytes()
    assert one.observed.tolist() == batch.observed.tolist()


@pytest.mark.parametrize("kwargs, error, match", [
    (dict(measurements=np.zeros((2, 3, 3))), GeometryError, r"range_m of node 0\) is 0"),
    (dict(noise="paper"), ValidationError, "noise must be a MeasurementNoise"),
    (dict(noise=NOISES[:2]), ValidationError, "one MeasurementNoise per node"),
    (dict(prior="paper"), ValidationError, "prior must be a GaussianPrior or None"),
    (dict(pose_covariances=np.zeros((2, 3, 3))), ValidationError, r"shape \(3, 3, 3\)"),
    (dict(initial_state=np.zeros((2, 3))), ValidationError, r"initial_state must have shape"),
    (dict(initial_state=np.tile(np.r_[POSES_BC[0, :2], 0.0, 0.0], (2, 1))), GeometryError,
     "at node 0"),
    (dict(kernel=("tukey", 1.0)), ValidationError, "kernel must be"),
])
def test_bad_problems_are_refused_when_made(kwargs, error, match):
    z, _ = _z(2)
    args = dict(poses=POSES_BC, measurements=z)
    args.update(kwargs)
    with pytest.raises(error, match=match):
        FrameProblem(**args)


def test_the_one_initial_state_per_frame_and_vectorized_agree():
    z, obs = _z(12)
    for prior in (PAPER_PRIOR, None):
        for noise in (PAPER_NOISE, NOISES):
            problem = FrameProblem(poses=POSES_BC, measurements=z, observed=obs, noise=noise,
                                   prior=prior)
            floats = initial_states(problem, per_frame=True)
            np.testing.assert_allclose(floats, initial_states(problem), rtol=1e-12, atol=1e-12)
            # A frame starts from the same bits alone and in its batch.
            np.testing.assert_array_equal(initial_states(problem[4]), initial_states(problem)[[4]])
            np.testing.assert_array_equal(initial_states(problem[4], per_frame=True), floats[[4]])
    # Unobserved frames: the prior mean, or NaN for ML.
    none = np.zeros_like(obs)
    map_ = FrameProblem(poses=POSES_BC, measurements=z, observed=none)
    ml = FrameProblem(poses=POSES_BC, measurements=z, observed=none, prior=None)
    np.testing.assert_array_equal(initial_states(map_[0]), PAPER_PRIOR.mean[None])
    assert np.isnan(initial_states(ml[0])).all()
    # A given start is used as it is.
    x0 = np.tile([0.0, 3.0, 0.1, 0.2], (12, 1))
    np.testing.assert_array_equal(initial_states(map_.with_initial_state(x0)), x0)


def test_whitened_residuals_are_zero_at_the_truth_and_nan_where_unobserved():
    truth = np.array([[0.3, 3.0, 0.5, -0.2]])
    z = predict_measurements(truth[0], POSES_BC)[None]
    obs = np.array([[True, False, True]])
    problem = FrameProblem(poses=POSES_BC, measurements=z, observed=obs, noise=NOISES)
    e = whitened_residuals(problem, truth)
    np.testing.assert_allclose(e[0, [0, 2]], 0.0, atol=1e-12)
    assert np.isnan(e[0, 1]).all()
    moved = whitened_residuals(problem, truth + [0.01, 0, 0, 0])
    d = truth[0, :2] + [0.01, 0] - POSES_BC[0, :2]
    np.testing.assert_allclose(moved[0, 0, 0] * NOISES[0].range_m,
                               np.hypot(*d) - z[0, 0, 0], rtol=1e-9)
