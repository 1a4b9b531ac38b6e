"""Association of centroids across nodes (mmsnap_graph.fusion.association)."""

import numpy as np
import pytest

from factors.models import detection_to_global, measurement_model
from mmsnap_graph.fusion.association import associate_frame, detection_position_covariance, gate_threshold
from mmsnap_graph.errors import ValidationError, MmsnapError
from mmsnap_graph.data.noise import MeasurementNoise

from _shared import PAPER_NOISE, PAPER_SIGMAS, POSES_A, POSES_B, POSES_BC, TRACK_NOISE


def _measure(states, pose, rng, sigmas=PAPER_SIGMAS):
    h, _ = measurement_model(np.asarray(states, float), pose)
    z = h + rng.standard_normal(h.shape) * sigmas
    z[:, 1] = np.clip(z[:, 1], -np.pi, np.pi)
    return z


@pytest.mark.parametrize("pose", [POSES_B[0], POSES_B[1], POSES_A[1]])
def test_position_covariance_is_the_propagated_noise(pose):
    """J diag(sigma^2) J^T with J the numerical Jacobian of detection_to_global."""
    pose = np.asarray(pose)
    rng_m, omega = 4.0, 0.7
    eps = 1e-6
    j = np.column_stack([
        (detection_to_global(rng_m + eps, omega, pose) - detection_to_global(rng_m - eps, omega, pose)) / (2 * eps),
        (detection_to_global(rng_m, omega + eps, pose) - detection_to_global(rng_m, omega - eps, pose)) / (2 * eps),
    ])
    expected = j @ np.diag(PAPER_SIGMAS[:2] ** 2) @ j.T
    np.testing.assert_allclose(detection_position_covariance(rng_m, omega, pose, PAPER_NOISE), expected,
                               rtol=1e-7)


def test_position_covariance_stays_finite_at_end_fire():
    cov = detection_position_covariance(3.0, np.pi, POSES_B[0], PAPER_NOISE)
    assert np.all(np.isfinite(cov)) and np.linalg.eigvalsh(cov).min() > 0


def test_two_targets_are_paired_across_nodes_in_any_order():
    rng = np.random.default_rng(0)
    targets = np.array([[-0.5, 4.0, 0.3, 0.1], [2.0, 3.0, -0.2, 0.4]])
    # The angle noise of the paper is large; 0.05 rad keeps this a clean test.
    sig, noise = TRACK_NOISE.sigmas, TRACK_NOISE
    n_ok = 0
    for trial in range(50):
        z1 = _measure(targets, POSES_B[0], rng, sig)
        z2 = _measure(targets[::-1], POSES_B[1], rng, sig)  # S2 lists them in reverse
        a = associate_frame([z1, z2], POSES_B, noise)
        assert len(a) == 2
        n_ok += a.members.tolist() == [[0, 1], [1, 0]]
    assert n_ok == 50


def test_group_position_is_the_information_weighted_mean():
    rng = np.random.default_rng(1)
    target = np.array([[0.5, 4.0, 0.0, 0.0]])
    z = [_measure(target, POSES_B[n], rng) for n in range(2)]
    a = associate_frame(z, POSES_B, PAPER_NOISE)
    p = [detection_to_global(z[n][0, 0], z[n][0, 1], POSES_B[n]) for n in range(2)]
    c = [detection_position_covariance(z[n][0, 0], z[n][0, 1], POSES_B[n], PAPER_NOISE) for n in range(2)]
    info = np.linalg.inv(c[0]) + np.linalg.inv(c[1])
    mean = np.linalg.solve(info, np.linalg.solve(c[0], p[0]) + np.linalg.solve(c[1], p[1]))
    np.testing.assert_allclose(a.position_m[0], mean, atol=1e-12)
    np.testing.assert_allclose(a.covariance_m2[0], np.linalg.inv(info), atol=1e-12)
    # Two range sigmas of 3.5 cm along orthogonal lines of sight: a few cm.
    assert np.linalg.norm(a.position_m[0] - target[0, :2]) < 0.2


def test_detections_outside_the_gate_start_their_own_groups():
    rng = np.random.default_rng(2)
    sig, noise = TRACK_NOISE.sigmas, TRACK_NOISE
    z1 = _measure([[0.5, 4.0, 0, 0]], POSES_B[0], rng, sig)
    z2 = _measure([[3.5, 1.5, 0, 0]], POSES_B[1], rng, sig)  # 3.9 m away
    a = associate_frame([z1, z2], POSES_B, noise)
    assert a.members.tolist() == [[0, -1], [-1, 0]]
    # With the paper's pi / 4 angle sigma (about 1 m across range at 4 m) the
    # same pair falls inside a 99.9 % gate: the gate follows the noise.
    z1 = _measure([[0.5, 4.0, 0, 0]], POSES_B[0], rng, PAPER_SIGMAS * [1, 0, 1])
    z2 = _measure([[1.5, 3.5, 0, 0]], POSES_B[1], rng, PAPER_SIGMAS * [1, 0, 1])
    assert associate_frame([z1, z2], POSES_B, PAPER_NOISE).members.tolist() == [[0, 0]]


def test_a_target_only_one_node_sees_and_empty_nodes():
    rng = np.random.default_rng(3)
    targets = np.array([[0.5, 4.0, 0, 0], [-1.5, 2.0, 0, 0]])
    z1 = _measure(targets, POSES_B[0], rng)
    z2 = _measure(targets[:1], POSES_B[1], rng)
    a = associate_frame([z1, z2], POSES_B, PAPER_NOISE)
    assert sorted(map(tuple, a.members.tolist())) == [(0, 0), (1, -1)]
    a = associate_frame([np.zeros((0, 3)), z2], POSES_B, PAPER_NOISE)
    assert a.members.tolist() == [[-1, 0]]
    a = associate_frame([np.zeros((0, 3)), np.zeros((0, 3))], POSES_B, PAPER_NOISE)
    assert len(a) == 0 and a.members.shape == (0, 2)


def test_three_nodes_build_one_group_per_target():
    rng = np.random.default_rng(4)
    poses = POSES_BC
    targets = np.array([[0.5, 3.5, 0, 0], [2.5, 2.0, 0, 0]])
    sig, noise = TRACK_NOISE.sigmas, TRACK_NOISE
    z = [_measure(targets, poses[n], rng, sig) for n in range(3)]
    a = associate_frame(z, poses, noise)
    assert a.members.tolist() == [[0, 0, 0], [1, 1, 1]]


def test_gate_threshold_is_chi_square_two_dof():
    assert gate_threshold(1 - np.exp(-4.5)) == pytest.approx(9.0)


@pytest.mark.parametrize(
    "args, kwargs, match",
    [
        (([np.zeros((0, 3))], POSES_B, PAPER_NOISE), {}, "measurements has 1 nodes but node_poses has 2"),
        (([np.zeros((0, 3))] * 2, np.zeros((2, 2)), PAPER_NOISE), {}, r"node_poses must have shape \(N, 3\)"),
        (([np.zeros((0, 3))] * 2, POSES_B, [1.0, 1.0, 1.0]), {}, "noise must be a MeasurementNoise, got list"),
        (([np.zeros((1, 2))] * 2, POSES_B, PAPER_NOISE), {}, r"measurements\[0\] must have shape \(K, 3\)"),
        (([np.full((1, 3), np.nan)] * 2, POSES_B, PAPER_NOISE), {}, r"measurements\[0\] must be finite"),
        (([np.zeros((0, 3))] * 2, POSES_B, PAPER_NOISE), dict(gate_probability=1.0), "gate_probability must be in"),
    ],
)
def test_invalid_input_raises(args, kwargs, match):
    with pytest.raises(ValidationError, match=match):
        associate_frame(*args, **kwargs)


POSES = np.array([[0.0, 0.0, 0.0], [6.0, 0.0, np.pi / 2]])


@pytest.mark.parametrize("bad", [(0.0, 0.0), (0.0, np.pi), (0.0, -np.pi), (1e-300, 0.3),
                                 (1e-9, 0.1)])
def test_a_degenerate_detection_gets_a_group_of_its_own(bad):
    z0 = np.array([[bad[0], bad[1], 0.1], [4.0, 0.2, 0.1]])
    z1 = np.array([[4.5, -0.4, 0.2]])
    assoc = associate_frame([z0, z1], POSES)
    degenerate = [g for g in range(len(assoc)) if assoc.members[g, 0] == 0]
    assert len(degenerate) == 1 and np.all(assoc.members[degenerate[0], 1:] == -1)
    assert np.all(np.isfinite(assoc.position_m))


def test_tiny_sigmas_do_not_stop_the_association():
    # The smallest sigmas fusion accepts (fusion.problem.SIGMA_MIN = 1e-60).
    noise = MeasurementNoise(range_m=1e-55, omega_rad=1e-55, doppler_mps=1e-55)
    assoc = associate_frame([np.array([[4.0, 0.2, 0.1]]), np.array([[4.5, -0.4, 0.2]])],
                            POSES, noise)
    assert len(assoc) == 2  # each alone: no usable position weight to gate with
    # Sigmas below that are refused up front with a typed error (no LinAlgError).
    with pytest.raises(MmsnapError, match="sigmas"):
        associate_frame([np.array([[4.0, 0.2, 0.1]]), np.array([[4.5, -0.4, 0.2]])], POSES,
                        MeasurementNoise(range_m=1e-300, omega_rad=1e-300, doppler_mps=1e-300))


def test_a_ghost_of_the_first_node_does_not_take_the_others_group():
    """Taken in node order, a ghost of S1 inside the gate of S2's detection
    took S2 and left S3 (which agrees with S2) alone; the frame is grouped
    largest consistent subset first, whatever the node order."""
    from mmsnap_graph.sim.simulator import CENTROID_NOISE

    poses = np.asarray(POSES_BC)
    truth = np.array([1.0, 3.5, 0.5, 0.2])
    z = [measurement_model(truth[None], p)[0][0] for p in poses]
    ghost = np.array([3.956, 0.614, 0.33])          # S1's centroid replaced
    for order in ([0, 1, 2], [2, 1, 0], [1, 0, 2]):
        meas = [ghost[None], z[1][None], z[2][None]]
        a = associate_frame([meas[i] for i in order], poses[order], CENTROID_NOISE)
        groups = sorted(sorted(order[n] for n in np.flatnonzero(m >= 0)) for m in a.members)
        assert groups == [[0], [1, 2]], (order, a.members)
    a = associate_frame([ghost[None], z[1][None], z[2][None]], poses, CENTROID_NOISE)
    true_group = int(np.flatnonzero(a.members[:, 1] >= 0)[0])
    np.testing.assert_allclose(a.position_m[true_group], truth[:2], atol=1e-9)


def test_a_ghost_among_many_nodes_is_dropped_not_followed():
    """Seven nodes on a circle facing its centre (more than
    MAX_SUBSET_NODES: the farthest detection is dropped until the rest
    agree): S1's ghost took S2 and left the other five on their own."""
    from mmsnap_graph.sim.simulator import CENTROID_NOISE

    ang = np.arange(7) * 2 * np.pi / 7
    poses = np.column_stack([6 * np.sin(ang), -6 * np.cos(ang), ang])
    truth = np.array([0.3, 0.2, 0.5, 0.2])
    z = [measurement_model(truth[None], p)[0][0][None] for p in poses]
    ghost = np.array([[6.6431, 0.185, 0.2239]])
    a = associate_frame([ghost] + z[1:], poses, CENTROID_NOISE)
    groups = sorted(sorted(np.flatnonzero(m >= 0).tolist()) for m in a.members)
    assert groups == [[0], [1, 2, 3, 4, 5, 6]], groups
