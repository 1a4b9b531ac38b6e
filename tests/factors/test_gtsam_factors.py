"""Measurement models and GTSAM factors: every Jacobian against
``gtsam.utils.numerical_derivative`` (through ``retract`` for Pose2), every
factor's ``linearize()`` against a numerically linearized factor, the omega
wrap near +-pi and the frame round trips (docs/CONVENTIONS.md)."""

from __future__ import annotations

import math

import gtsam
import numpy as np
import pytest
from gtsam.utils.numerical_derivative import (
    numericalDerivative11,
    numericalDerivative21,
    numericalDerivative22,
)
from numpy.testing import assert_allclose

from factors import ROBUST_K_DEFAULT, models
from factors.gtsam_factors import (
    constant_velocity_factor,
    frame_measurement_factor,
    measurement_noise,
    node_measurement_factor,
    pose_measurement_factor,
    scalar_measurement_factor,
    state_prior_factor,
)

from _shared import PAPER_SIGMAS

N_CONFIGS = 40


def random_config(rng):
    """A node pose and a target state at least 0.5 m away, within +-80 deg of
    broadside (omega away from +-pi so numerical derivatives don't cross the wrap)."""
    pose = np.array([rng.uniform(-5, 5), rng.uniform(-5, 5), rng.uniform(-np.pi, np.pi)])
    r = rng.uniform(0.5, 12.0)
    theta = rng.uniform(-np.radians(80), np.radians(80))
    p = models.local_to_global(np.array([r * np.sin(theta), r * np.cos(theta)]), pose)
    state = np.concatenate([p, rng.normal(0.0, 2.0, 2)])
    return pose, state


def configs(seed, n=N_CONFIGS):
    rng = np.random.default_rng(seed)
    return [random_config(rng) for _ in range(n)]


# ---------------------------------------------------------------------------
# Pure models


def test_measurement_model_matches_independent_geometry():
    """Reference values from geometry alone (no shared formula): range as a
    distance, omega = pi sin(theta) with theta the bearing from broadside in
    the node frame (``Pose2.transformTo``), Doppler as the rate of change of
    the range along the velocity (central difference)."""
    for pose, state in configs(1):
        p, vel = state[:2], state[2:]
        u, v = gtsam.Pose2(*pose).transformTo(p)
        theta = math.atan2(u, v)  # from broadside (local y) towards the array axis (local x)
        eps = 1e-6
        rate = (np.linalg.norm(p + eps * vel - pose[:2]) - np.linalg.norm(p - eps * vel - pose[:2])) / (2 * eps)
        expected = [math.dist(p, pose[:2]), math.pi * math.sin(theta), rate]
        assert_allclose(models.measurement_model(state, pose)[0], expected, rtol=1e-7, atol=1e-8)
        assert_allclose(models.predict_measurements(state, pose), expected, rtol=1e-7, atol=1e-8)


def test_measurement_model_jacobian_matches_numerical():
    for pose, state in configs(2):
        _, jac = models.measurement_model(state, pose)
        num = numericalDerivative11(lambda s: models.measurement_model(s, pose)[0], state)
        assert_allclose(jac, num, rtol=1e-6, atol=1e-8)


def test_measurement_model_pose_jacobians_through_retract():
    """Form (b): d h / d pose in GTSAM's body-frame tangent, checked by
    differentiating through ``Pose2.retract``."""

    def h_of(pose2: gtsam.Pose2, state):
        return models.measurement_model_pose(
            np.array([pose2.x(), pose2.y(), pose2.theta()]), state
        )[0]

    for pose, state in configs(3):
        pose2 = gtsam.Pose2(*pose)
        h, j_pose, j_state = models.measurement_model_pose(pose, state)
        assert_allclose(h, models.measurement_model(state, pose)[0], rtol=0, atol=1e-12)
        assert_allclose(j_pose, numericalDerivative21(h_of, pose2, state), rtol=1e-6, atol=1e-8)
        assert_allclose(j_state, numericalDerivative22(h_of, pose2, state), rtol=1e-6, atol=1e-8)


def test_models_broadcast_over_leading_axes():
    rng = np.random.default_rng(4)
    cfg = [random_config(rng) for _ in range(12)]
    poses = np.array([c[0] for c in cfg]).reshape(3, 4, 3)
    states = np.array([c[1] for c in cfg]).reshape(3, 4, 4)
    h, jac = models.measurement_model(states, poses)
    assert h.shape == (3, 4, 3) and jac.shape == (3, 4, 3, 4)
    for k, (pose, state) in enumerate(cfg):
        hk, jk = models.measurement_model(state, pose)
        assert_allclose(h.reshape(-1, 3)[k], hk, rtol=0, atol=1e-12)
        assert_allclose(jac.reshape(-1, 3, 4)[k], jk, rtol=0, atol=1e-12)


def test_predict_measurements_equals_measurement_model():
    rng = np.random.default_rng(23)
    cfg = [random_config(rng) for _ in range(30)]
    poses = np.array([c[0] for c in cfg])
    states = np.array([c[1] for c in cfg])
    assert_allclose(models.predict_measurements(states, poses), models.measurement_model(states, poses)[0], rtol=1e-14, atol=1e-14)
    # broadcasting: many states against one node, as over a grid
    h = models.predict_measurements(states[:, None, :], poses[None, :3])
    assert h.shape == (30, 3, 3)
    assert_allclose(h, models.measurement_model(states[:, None, :], poses[None, :3])[0], rtol=1e-14, atol=1e-14)


def test_scalar_kernel_equals_vectorized_model():
    for pose, state in configs(5, 100):
        node = (pose[0], pose[1], math.cos(pose[2]), math.sin(pose[2]))
        r, w, v, jac = models.measurement_model_scalar(*state.tolist(), *node)
        h, j = models.measurement_model(state, pose)
        assert_allclose([r, w, v], h, rtol=1e-14, atol=1e-14)
        assert_allclose(np.array(jac).reshape(3, 4), j, rtol=1e-13, atol=1e-14)
        r2, w2, v2, jac2, j_pose = models.measurement_model_scalar(
            *state.tolist(), *node, pose_jacobian=True)
        assert (r2, w2, v2, jac2) == (r, w, v, jac)
        _, jp_vec, _ = models.measurement_model_pose(pose, state)
        assert_allclose(np.array(j_pose).reshape(3, 3), jp_vec, rtol=1e-12, atol=1e-13)


def test_scalar_kernel_jacobians_through_retract():
    """The scalar kernel's own state and pose Jacobians against numerical
    derivatives (the pose one through ``Pose2.retract``)."""

    def h_of(pose2: gtsam.Pose2, state):
        out = models.measurement_model_scalar(
            *state.tolist(), pose2.x(), pose2.y(), math.cos(pose2.theta()), math.sin(pose2.theta()))
        return np.array(out[:3])

    for pose, state in configs(24, 30):
        pose2 = gtsam.Pose2(*pose)
        *_, jac, j_pose = models.measurement_model_scalar(
            *state.tolist(), pose[0], pose[1], math.cos(pose[2]), math.sin(pose[2]),
            pose_jacobian=True)
        assert_allclose(np.array(j_pose).reshape(3, 3), numericalDerivative21(h_of, pose2, state),
                        rtol=1e-6, atol=1e-8)
        assert_allclose(np.array(jac).reshape(3, 4), numericalDerivative22(h_of, pose2, state),
                        rtol=1e-6, atol=1e-8)


def test_scalar_kernel_raises_at_the_node_position():
    with pytest.raises(ZeroDivisionError):
        models.measurement_model_scalar(1.0, 2.0, 0.0, 0.0, 1.0, 2.0, 1.0, 0.0)


@pytest.mark.parametrize("angle", [-7.0, -np.pi, -3.0, -1e-9, 0.0, 3.0, np.pi, np.pi - 1e-12, 9.5])
def test_wrap_angle_scalar_matches_numpy(angle):
    assert models.wrap_angle_scalar(angle) == models.wrap_angle(angle)
    assert -np.pi <= models.wrap_angle_scalar(angle) < np.pi


def test_omega_residual_wraps_near_pi():
    """A prediction just below +pi and a measurement just above -pi differ by a
    small angle, not by ~2 pi, in the model residual and in the factors."""
    eps = 0.01
    predicted = np.array([4.0, np.pi - eps, 0.3])
    measured = np.array([4.0, -np.pi + eps, 0.3])
    assert_allclose(models.residual(predicted, measured), [0.0, -2 * eps, 0.0], atol=1e-12)
    assert_allclose(models.residual(measured, predicted), [0.0, 2 * eps, 0.0], atol=1e-12)
    # A target almost along the array axis of a node at the origin: omega ~ pi.
    pose = np.array([0.0, 0.0, 0.0])
    state = np.array([4.0, 0.02, 0.1, -0.2])
    h, _ = models.measurement_model(state, pose)
    assert np.pi - h[1] < 0.1
    z = np.array([h[0], models.wrap_angle(h[1] + 2 * eps), h[2]])
    assert z[1] < 0  # the measurement wrapped to the other end of (-pi, pi]
    noise = measurement_noise(PAPER_SIGMAS)
    values = gtsam.Values()
    values.insert(0, state)
    for factor in (
        node_measurement_factor(0, pose, z, noise),
        frame_measurement_factor(0, pose[None], z[None], noise),
    ):
        assert_allclose(factor.unwhitenedError(values), [0.0, -2 * eps, 0.0], atol=1e-9)
    values.insert(1, gtsam.Pose2(*pose))
    pose_factor = pose_measurement_factor(1, 0, z, noise)
    assert_allclose(pose_factor.unwhitenedError(values), [0.0, -2 * eps, 0.0], atol=1e-9)


# ---------------------------------------------------------------------------
# Frames


def test_local_to_global_matches_pose2_transform_from():
    rng = np.random.default_rng(6)
    for _ in range(50):
        pose = np.array([rng.uniform(-9, 9), rng.uniform(-9, 9), rng.uniform(-4, 4)])
        p_local = rng.uniform(-10, 10, 2)
        expected = gtsam.Pose2(*pose).transformFrom(p_local)
        assert_allclose(models.local_to_global(p_local, pose), expected, rtol=0, atol=1e-12)
        back = models.global_to_local(expected, pose)
        assert_allclose(back, p_local, rtol=0, atol=1e-12)
        assert_allclose(back, gtsam.Pose2(*pose).transformTo(expected), rtol=0, atol=1e-12)


def test_detection_round_trip_through_the_model():
    """h(state) -> detection_to_local -> local_to_global returns the target's
    position, and detection_to_local agrees with transformTo."""
    for pose, state in configs(7, 60):
        h, _ = models.measurement_model(state, pose)
        p_local = models.detection_to_local(h[0], h[1])
        assert p_local[1] > 0  # in front of the node (|theta| < 90 deg)
        assert_allclose(p_local, gtsam.Pose2(*pose).transformTo(state[:2]), rtol=0, atol=1e-9)
        assert_allclose(
            models.local_to_global(p_local, pose),
            gtsam.Pose2(*pose).transformFrom(p_local),
            rtol=0,
            atol=1e-12,
        )
        assert_allclose(models.detection_to_global(h[0], h[1], pose), state[:2], atol=1e-9)


def test_detection_to_local_clips_omega_beyond_pi():
    assert_allclose(models.detection_to_local(2.0, 4.0), [2.0, 0.0], atol=1e-12)
    assert_allclose(models.detection_to_local(2.0, -4.0), [-2.0, 0.0], atol=1e-12)


def test_detection_to_local_scalar_equals_vectorized():
    rng = np.random.default_rng(25)
    for rng_m, omega in zip(rng.uniform(0.1, 12, 50), rng.uniform(-4.5, 4.5, 50)):
        assert_allclose(models.detection_to_local_scalar(float(rng_m), float(omega)),
                        models.detection_to_local(rng_m, omega), rtol=1e-15, atol=1e-15)


def test_detection_jacobian_matches_numerical():
    rng = np.random.default_rng(26)
    for rng_m, omega in zip(rng.uniform(0.3, 12, 40), rng.uniform(-2.9, 2.9, 40)):
        z = np.array([rng_m, omega])
        num = numericalDerivative11(lambda q: models.detection_to_local(q[0], q[1]), z)
        assert_allclose(models.detection_jacobian(rng_m, omega), num, rtol=1e-6, atol=1e-8)
    # vectorized: one Jacobian per detection
    jac = models.detection_jacobian(np.array([2.0, 3.0]), np.array([0.1, -0.5]))
    assert jac.shape == (2, 2, 2)
    assert_allclose(jac[1], models.detection_jacobian(3.0, -0.5), rtol=1e-15)


def test_detection_jacobian_floors_cos_at_end_fire():
    jac = models.detection_jacobian(2.0, np.pi)  # sin(theta) = 1, cos(theta) = 0
    c = models.DETECTION_MIN_COS
    assert_allclose(jac, [[1.0, 2.0 / np.pi], [c, -2.0 / (np.pi * c)]], rtol=1e-15)
    assert np.all(np.isfinite(models.detection_jacobian(2.0, 5.0)))


def test_detection_covariance_matches_monte_carlo():
    """First-order local and global covariances against the scatter of
    detections mapped through the exact inverse (small sigmas: linear regime)."""
    rng = np.random.default_rng(27)
    sr, so, n = 0.01, 0.01, 40_000
    for rng_m, omega, pose in [(4.0, 0.3, [1.0, -2.0, 0.7]), (2.5, -1.9, [0.0, 7.0, np.pi])]:
        rs = rng_m + sr * rng.standard_normal(n)
        ws = omega + so * rng.standard_normal(n)
        cov_local = models.detection_covariance_local(rng_m, omega, sr, so)
        cov_global = models.detection_covariance_global(rng_m, omega, np.array(pose), sr, so)
        for cov, pts in ((cov_local, models.detection_to_local(rs, ws)),
                         (cov_global, models.detection_to_global(rs, ws, np.array(pose)))):
            emp = np.cov(pts.T)
            scale = np.sqrt(np.outer(np.diag(cov), np.diag(cov)))
            assert_allclose(emp / scale, cov / scale, atol=0.03)
        # rotation only: same eigenvalues in both frames
        assert_allclose(np.linalg.eigvalsh(cov_global), np.linalg.eigvalsh(cov_local), rtol=1e-12)


def test_detection_covariance_broadcasts_over_detections_and_poses():
    r = np.array([2.0, 3.0, 4.0])
    w = np.array([0.1, -0.5, 1.0])
    poses = np.array([[0.0, 0.0, 0.0], [1.0, 2.0, 0.5], [0.0, 7.0, np.pi]])
    cov = models.detection_covariance_global(r, w, poses, 0.035, np.pi / 4)
    assert cov.shape == (3, 2, 2)
    for k in range(3):
        assert_allclose(cov[k], models.detection_covariance_global(r[k], w[k], poses[k], 0.035, np.pi / 4),
                        rtol=1e-14)


def test_configuration_c_nodes_face_each_other():
    s2 = np.array([0.0, 7.0, np.pi])
    # S1 (the origin) seen from S2 is straight ahead: omega 0, local y = 7.
    h, _ = models.measurement_model(np.array([0.0, 0.0, 0.0, 0.0]), s2)
    assert_allclose(h[:2], [7.0, 0.0], atol=1e-12)
    assert_allclose(models.global_to_local([0.0, 0.0], s2), [0.0, 7.0], atol=1e-12)


# ---------------------------------------------------------------------------
# Whole factors: linearize() against a numerically linearized factor


def numerical_linearization(factor, values, keys):
    """Whitened Jacobian blocks (by central differences through retract) and
    the whitened error of ``factor`` at ``values``."""
    blocks = []
    for key in keys:
        def err_at(x, key=key):
            v = gtsam.Values(values)
            v.update(key, x)
            return factor.whitenedError(v)

        base = values.atPose2(key) if _is_pose(values, key) else values.atVector(key)
        blocks.append(numericalDerivative11(err_at, base, delta=1e-6))
    return np.hstack(blocks), factor.whitenedError(values)


def _is_pose(values, key):
    try:
        values.atPose2(key)
        return True
    except RuntimeError:
        return False


def check_linearize(factor, values, keys, rtol=1e-6, atol=1e-6):
    assert list(factor.keys()) == list(keys)
    lin = factor.linearize(values)
    a, b = lin.jacobian()
    num_a, werr = numerical_linearization(factor, values, keys)
    assert_allclose(b, -werr, rtol=1e-12, atol=1e-12)
    scale = max(1.0, np.abs(num_a).max())
    assert_allclose(a, num_a, rtol=rtol, atol=atol * scale)


def noisy_measurement(rng, pose, state):
    h, _ = models.measurement_model(state, pose)
    z = h + rng.normal(size=3) * PAPER_SIGMAS * 0.3
    z[1] = models.wrap_angle(z[1])
    return z


def test_node_measurement_factor_linearize():
    rng = np.random.default_rng(8)
    noise = measurement_noise(PAPER_SIGMAS)
    for pose, state in configs(9, 25):
        values = gtsam.Values()
        values.insert(3, state)
        check_linearize(node_measurement_factor(3, pose, noisy_measurement(rng, pose, state), noise), values, [3])


@pytest.mark.parametrize(
    "components", [("range",), ("omega",), ("doppler",), ("range", "doppler"), ("omega", "doppler")]
)
def test_node_measurement_factor_subsets_linearize(components):
    rng = np.random.default_rng(10)
    noise = measurement_noise(PAPER_SIGMAS[[models.MEASUREMENT_NAMES.index(
        {"range": "range_m", "omega": "omega_rad", "doppler": "doppler_mps"}[c]) for c in components]])
    for pose, state in configs(11, 10):
        z = noisy_measurement(rng, pose, state)
        values = gtsam.Values()
        values.insert(0, state)
        factor = node_measurement_factor(0, pose, z, noise, components)
        check_linearize(factor, values, [0])
        full = node_measurement_factor(0, pose, z, measurement_noise(PAPER_SIGMAS))
        rows = [("range", "omega", "doppler").index(c) for c in components]
        assert_allclose(factor.unwhitenedError(values), full.unwhitenedError(values)[rows], atol=1e-15)


@pytest.mark.parametrize("component", ["range", "omega", "doppler"])
def test_scalar_measurement_factor_linearize(component):
    rng = np.random.default_rng(12)
    idx = ("range", "omega", "doppler").index(component)
    for pose, state in configs(13, 10):
        z = noisy_measurement(rng, pose, state)
        values = gtsam.Values()
        values.insert(0, state)
        factor = scalar_measurement_factor(0, pose, component, z[idx], PAPER_SIGMAS[idx])
        check_linearize(factor, values, [0])
        h, _ = models.measurement_model(state, pose)
        assert_allclose(factor.unwhitenedError(values), [models.residual(h, z)[idx]], atol=1e-12)


def test_frame_measurement_factor_linearize_and_equivalence():
    """The one-factor-per-frame form equals one node factor per node."""
    rng = np.random.default_rng(14)
    for n_nodes in (1, 2, 3):
        noise_frame = measurement_noise(np.tile(PAPER_SIGMAS, n_nodes))
        noise_node = measurement_noise(PAPER_SIGMAS)
        for _ in range(8):
            state = np.array([rng.uniform(-1, 1), rng.uniform(3, 6), *rng.normal(0, 1, 2)])
            poses = np.array(
                [[rng.uniform(-4, 4), rng.uniform(-4, 0), rng.uniform(-0.5, 0.5)] for _ in range(n_nodes)]
            )
            z = np.array([noisy_measurement(rng, p, state) for p in poses])
            values = gtsam.Values()
            values.insert(0, state)
            frame = frame_measurement_factor(0, poses, z, noise_frame)
            check_linearize(frame, values, [0])
            nodes = [node_measurement_factor(0, p, zi, noise_node) for p, zi in zip(poses, z)]
            assert_allclose(
                frame.unwhitenedError(values),
                np.concatenate([f.unwhitenedError(values) for f in nodes]),
                rtol=0,
                atol=1e-14,
            )
            assert frame.error(values) == pytest.approx(sum(f.error(values) for f in nodes), rel=1e-13)


def test_frame_measurement_factor_rejects_mismatched_rows():
    with pytest.raises(ValueError, match="measurements has 1 rows but node_poses has 2"):
        frame_measurement_factor(0, np.zeros((2, 3)), np.ones((1, 3)), measurement_noise(np.ones(6)))


def test_pose_measurement_factor_linearize():
    rng = np.random.default_rng(15)
    noise = measurement_noise(PAPER_SIGMAS)
    for pose, state in configs(16, 25):
        values = gtsam.Values()
        values.insert(7, gtsam.Pose2(*pose))
        values.insert(2, state)
        factor = pose_measurement_factor(7, 2, noisy_measurement(rng, pose, state), noise)
        check_linearize(factor, values, [7, 2])


def test_pose_measurement_factor_equals_node_factor_at_known_pose():
    rng = np.random.default_rng(17)
    noise = measurement_noise(PAPER_SIGMAS)
    for pose, state in configs(18, 10):
        z = noisy_measurement(rng, pose, state)
        values = gtsam.Values()
        values.insert(0, state)
        values.insert(1, gtsam.Pose2(*pose))
        a = pose_measurement_factor(1, 0, z, noise).unwhitenedError(values)
        b = node_measurement_factor(0, pose, z, noise).unwhitenedError(values)
        assert_allclose(a, b, rtol=0, atol=1e-12)


@pytest.mark.parametrize("robust", [None, "huber", "cauchy"])
def test_robust_noise_models_linearize(robust):
    rng = np.random.default_rng(19)
    noise = measurement_noise(PAPER_SIGMAS, robust=robust)
    pose, state = configs(20, 1)[0]
    z = noisy_measurement(rng, pose, state) + np.array([0.2, 0.0, 0.5])  # an outlier
    values = gtsam.Values()
    values.insert(0, state)
    factor = node_measurement_factor(0, pose, z, noise)
    lin = factor.linearize(values)
    a, _ = lin.jacobian()
    # A robust kernel only rescales rows: same direction as the plain factor.
    a_plain, _ = node_measurement_factor(0, pose, z, measurement_noise(PAPER_SIGMAS)).linearize(values).jacobian()
    weights = np.linalg.norm(a, axis=1) / np.linalg.norm(a_plain, axis=1)
    assert_allclose(a, a_plain * weights[:, None], rtol=1e-9, atol=1e-12)
    if robust is None:
        assert_allclose(weights, 1.0, rtol=1e-12)
    else:
        assert np.all(weights <= 1.0 + 1e-12) and weights.min() < 0.999


@pytest.mark.parametrize("robust", ["huber", "cauchy"])
def test_measurement_noise_default_k_is_the_shared_constant(robust):
    """Both kernels weigh a residual of 2 k by 1/2 (Huber: k / |x|; Cauchy:
    1 / (1 + (x / k)^2) at x = k): the default k is ROBUST_K_DEFAULT."""
    k = ROBUST_K_DEFAULT[robust]
    assert k == {"huber": 1.345, "cauchy": 2.5}[robust]
    x = 2 * k if robust == "huber" else k
    assert measurement_noise(PAPER_SIGMAS, robust).robust().weight(x) == pytest.approx(0.5, rel=1e-12)
    assert measurement_noise(PAPER_SIGMAS, robust, 1.0).robust().weight(2.0 if robust == "huber" else 1.0) \
        == pytest.approx(0.5, rel=1e-12)


def test_measurement_noise_rejects_unknown_kernel():
    with pytest.raises(ValueError, match="robust='tukey' must be None"):
        measurement_noise(PAPER_SIGMAS, robust="tukey")


def test_state_prior_factor_linearize():
    rng = np.random.default_rng(21)
    for _ in range(10):
        mean = rng.normal(0, 2, 4)
        sigmas = rng.uniform(0.5, 4, 4)
        state = rng.normal(0, 3, 4)
        values = gtsam.Values()
        values.insert(5, state)
        factor = state_prior_factor(5, mean, sigmas)
        check_linearize(factor, values, [5], atol=1e-8)
        assert factor.error(values) == pytest.approx(0.5 * np.sum(((state - mean) / sigmas) ** 2))


def test_constant_velocity_factor_linearize_and_noise():
    rng = np.random.default_rng(22)
    dt, sigma_a = 0.15, 0.2
    for _ in range(10):
        a = rng.normal(0, 2, 4)
        b = a + rng.normal(0, 0.1, 4)
        values = gtsam.Values()
        values.insert(1, a)
        values.insert(2, b)
        factor = constant_velocity_factor(1, 2, dt, sigma_a)
        check_linearize(factor, values, [1, 2], atol=1e-8)
        f = np.eye(4)
        f[0, 2] = f[1, 3] = dt
        assert_allclose(factor.unwhitenedError(values), b - f @ a, atol=1e-14)
    # The noise is the continuous white-acceleration covariance (docstring):
    q = sigma_a**2 * dt
    cov_axis = q * np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])
    factor = constant_velocity_factor(1, 2, dt, sigma_a)
    r = factor.noiseModel().R()
    cov = np.linalg.inv(r.T @ r)
    assert_allclose(cov[np.ix_([0, 2], [0, 2])], cov_axis, rtol=1e-9, atol=1e-15)
    assert_allclose(cov[np.ix_([1, 3], [1, 3])], cov_axis, rtol=1e-9, atol=1e-15)
    assert_allclose(cov[0, 1], 0.0, atol=1e-15)
