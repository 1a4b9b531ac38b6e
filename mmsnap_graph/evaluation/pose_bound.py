"""What the detections of a recording allow: a Cramer-Rao bound on the node
poses, against which sparse clouds are compared with dense ones.

Two steps, both numpy, both given the truth (a simulated recording):

- :func:`centroid_residuals`: each centroid of a node against the true torso
  states of the same frame (nearest target in range and spatial frequency,
  at the true node pose): residuals ``z - h(x_true)`` in range, omega and
  Doppler; their spread is the *actual* error of the centroids the
  calibration measures against (body extent, not the simulator's nominal
  sigmas).
- :func:`pose_crb`: the Fisher information of the non-reference node poses
  (GTSAM body tangent ``(dx_b, dy_b, dphi)``, the reference fixed: the
  calibration's gauge) from those detections, white Gaussian errors of the
  given sigmas, at the true poses and states. With ``nuisance=True`` every
  (frame, target) state ``(x, y, vx, vy)`` is an unknown too (eliminated by
  its Schur complement); with ``nuisance=False`` the trajectory is known,
  which is a lower bound optimistic for every estimator.

The bound is a property of the data: no estimator unbiased on them does
better. Correlated errors (a torso centroid's body extent drifts slowly)
make the white-noise bound optimistic; :func:`lag1_correlation` measures
that.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from numpy.typing import NDArray

from factors.models import measurement_model_pose, predict_measurements, wrap_angle

from ..data.recording import Detections, Truth
from ..errors import ValidationError

__all__ = ["centroid_residuals", "residual_sigmas", "lag1_correlation", "pose_crb",
           "DEFAULT_GATE"]

#: Residuals beyond these (range m, omega rad, Doppler m/s) are false alarms
#: or another person's points, not the centroid's spread.
DEFAULT_GATE = (1.0, 1.0, 2.0)


def centroid_residuals(centroids: Detections, truth: Truth, node_pose: NDArray,
                       gate: tuple[float, float, float] = DEFAULT_GATE
                       ) -> tuple[NDArray, NDArray, NDArray]:
    """``(frame (K,), target_id (K,), residual (K, 3))`` of the centroids
    within ``gate`` of their nearest true target (range + omega distance;
    measurement order range_m, omega_rad, doppler_mps)."""
    pose = np.asarray(node_pose, dtype=float)
    if pose.shape != (3,):
        raise ValidationError(f"node_pose must have shape (3,), got {pose.shape}")
    z = np.column_stack([centroids.range_m, centroids.omega_rad, centroids.doppler_mps])
    best = np.full(len(z), np.inf)
    tid = np.full(len(z), -1)
    res = np.zeros_like(z)
    for t in np.unique(truth.target_id):
        frames, states = truth.target(int(t))
        at = np.searchsorted(frames, centroids.frame)
        ok = (at < frames.size) & (frames[np.minimum(at, frames.size - 1)] == centroids.frame)
        h = predict_measurements(states[np.minimum(at, frames.size - 1)], pose)
        r = z - h
        r[:, 1] = wrap_angle(r[:, 1])
        d = np.where(ok, np.abs(r[:, 0]) + np.abs(r[:, 1]), np.inf)
        closer = d < best
        best[closer], tid[closer], res[closer] = d[closer], int(t), r[closer]
    keep = (tid >= 0) & np.all(np.abs(res) <= np.asarray(gate, float), axis=1)
    return centroids.frame[keep], tid[keep], res[keep]


def residual_sigmas(residual: NDArray) -> NDArray:
    """(3,) rms of ``residual (K, 3)`` about its mean (the spread an
    estimator sees; a common bias is a separate matter)."""
    r = np.asarray(residual, dtype=float)
    if r.ndim != 2 or r.shape[1] != 3 or r.shape[0] < 2:
        raise ValidationError(f"residual must have shape (K >= 2, 3), got {r.shape}")
    return r.std(axis=0)


def lag1_correlation(frame: NDArray, target_id: NDArray, residual: NDArray) -> NDArray:
    """(3,) lag-1 autocorrelation of each component over consecutive frames
    of the same target (pairs of centroids one frame apart)."""
    order = np.lexsort((frame, target_id))
    f, t, r = frame[order], target_id[order], residual[order] - residual.mean(axis=0)
    pair = (np.diff(f) == 1) & (np.diff(t) == 0)
    if not pair.any():
        return np.full(3, np.nan)
    a, b = r[:-1][pair], r[1:][pair]
    return (a * b).mean(axis=0) / np.sqrt((a * a).mean(axis=0) * (b * b).mean(axis=0))


def _true_states(truth: Truth, frame: NDArray, target_id: NDArray) -> NDArray:
    key = truth.frame.astype(np.int64) * 1_000_003 + truth.target_id
    order = np.argsort(key)
    want = frame.astype(np.int64) * 1_000_003 + target_id
    at = order[np.minimum(np.searchsorted(key[order], want), order.size - 1)]
    missing = key[at] != want
    if missing.any():
        i = int(np.argmax(missing))
        raise ValidationError(f"(frame, target_id) = ({int(frame[i])}, {int(target_id[i])}) "
                              f"has no truth state")
    return truth.state[at]


def pose_crb(observations: Mapping[str, tuple[NDArray, NDArray, NDArray]], truth: Truth,
             node_poses: Mapping[str, NDArray], reference: str, *,
             nuisance: bool = True) -> dict[str, NDArray]:
    """Cramer-Rao bound (3, 3) of each non-reference node's pose.

    observations : node -> ``(frame (K,), target_id (K,), sigmas (3,) or
        (K, 3))``: which (frame, target) the node detected and the error
        sigmas (range m, omega rad, Doppler m/s) of those detections.
    node_poses : node -> (3,) true pose; the reference's is fixed.
    nuisance : every (frame, target) state unknown (True) or known (False).
    Returns node -> covariance in the body tangent ``(dx_b, dy_b, dphi)``.
    """
    free = [n for n in observations if n != reference]
    if reference not in node_poses or any(n not in node_poses for n in observations):
        raise ValidationError(f"node_poses must hold every observing node and the "
                              f"reference {reference!r}")
    if not free:
        raise ValidationError("observations hold no node but the reference")
    n_p = 3 * len(free)
    info = np.zeros((n_p, n_p))
    groups: dict[tuple[int, int], list] = {}
    for name, (frame, tid, sig) in observations.items():
        frame, tid = np.asarray(frame, np.int64), np.asarray(tid, np.int64)
        sig = np.broadcast_to(np.asarray(sig, float), (frame.size, 3))
        x = _true_states(truth, frame, tid)
        _, j_pose, j_state = measurement_model_pose(np.asarray(node_poses[name], float), x)
        w = 1.0 / sig ** 2                                            # (K, 3)
        k = free.index(name) if name in free else -1
        for i in range(frame.size):
            groups.setdefault((int(frame[i]), int(tid[i])), []).append(
                (k, j_pose[i], j_state[i], w[i]))
    for obs in groups.values():
        info += _group_information(obs, n_p, nuisance)
    if np.linalg.matrix_rank(info) < n_p:
        raise ValidationError("the observations do not determine every node's pose "
                              "(singular Fisher information)")
    cov = np.linalg.inv(info)
    return {n: cov[3 * i:3 * i + 3, 3 * i:3 * i + 3] for i, n in enumerate(free)}


def _group_information(obs: list, n_p: int, nuisance: bool) -> NDArray:
    """One (frame, target)'s information on the poses, its state eliminated
    (Schur complement) when it is a nuisance parameter."""
    j = np.zeros((3 * len(obs), n_p + 4))
    w = np.zeros(3 * len(obs))
    for i, (k, jp, js, wi) in enumerate(obs):
        if k >= 0:
            j[3 * i:3 * i + 3, 3 * k:3 * k + 3] = jp
        j[3 * i:3 * i + 3, n_p:] = js
        w[3 * i:3 * i + 3] = wi
    full = j.T @ (w[:, None] * j)
    a = full[:n_p, :n_p]
    if not nuisance:
        return a
    b, c = full[:n_p, n_p:], full[n_p:, n_p:]
    # c may be singular (one node, 3 measurements, 4 unknowns); b's rows lie
    # in c's range, so the pseudo-inverse gives the exact Schur complement.
    return a - b @ np.linalg.pinv(c, rcond=1e-10, hermitian=True) @ b.T


def consensus_sigmas(residuals: Mapping[str, tuple[NDArray, NDArray, NDArray]], truth: Truth,
                     node_poses: Mapping[str, NDArray], *, n_iter: int = 3
                     ) -> dict[str, NDArray]:
    """Each node's error sigmas (3,) about the per-frame *consensus* of the
    nodes, not the true torso: the part of the centroids' error common to
    every node (the body's scatterers off its torso point, seen alike from
    every side) moves the fused state, not the poses, and is no noise to a
    calibration with the states unknown.

    residuals : node -> ``(frame (K,), target_id (K,), residual (K, 3))``
        from :func:`centroid_residuals`.
    Per (frame, target) seen by two or more nodes the state offset is fitted
    by weighted least squares at the true poses (Gauss-Newton from the true
    state); ``sigma^2 = sum r^2 / sum
    (1 - leverage)`` per node and component, iterated ``n_iter`` times (the
    weights depend on the sigmas).
    """
    names = list(residuals)
    groups: dict[tuple[int, int], list] = {}
    for i, name in enumerate(names):
        frame, tid, res = residuals[name]
        x = _true_states(truth, np.asarray(frame, np.int64), np.asarray(tid, np.int64))
        pose = np.asarray(node_poses[name], float)
        z = predict_measurements(x, pose) + np.asarray(res, float)
        for f, t, zi, xi in zip(frame, tid, z, x):
            groups.setdefault((int(f), int(t)), []).append((i, pose, zi, xi))
    groups = {k: g for k, g in groups.items() if len(g) >= 2}
    sig = np.array([residual_sigmas(residuals[n][2]) for n in names])
    for _ in range(int(n_iter)):
        ss, dof = np.zeros_like(sig), np.zeros_like(sig)
        for g in groups.values():
            idx = np.array([i for i, _, _, _ in g])
            e, lev = _consensus_fit(np.array([p for _, p, _, _ in g]),
                                    np.array([z for _, _, z, _ in g]), g[0][3],
                                    sig[idx])
            np.add.at(ss, idx, e ** 2)
            np.add.at(dof, idx, 1.0 - lev)
        sig = np.sqrt(ss / dof)
    return {n: sig[i] for i, n in enumerate(names)}


def _consensus_fit(poses: NDArray, z: NDArray, x0: NDArray, sig: NDArray,
                   n_steps: int = 3) -> tuple[NDArray, NDArray]:
    """Weighted least-squares state of one (frame, target) from its nodes'
    detections ``z (M, 3)`` at ``poses (M, 3)`` (Gauss-Newton from the true
    state ``x0``): residuals and leverages, (M, 3) each."""
    w = 1.0 / sig.reshape(-1) ** 2
    x = x0.copy()
    for _ in range(n_steps):
        h, j = measurement_model_pose(poses, np.broadcast_to(x, (len(z), 4)))[::2]
        e = z - h
        e[:, 1] = wrap_angle(e[:, 1])
        j = j.reshape(-1, 4)
        cinv = np.linalg.pinv(j.T @ (w[:, None] * j), rcond=1e-10, hermitian=True)
        x = x + cinv @ (j.T @ (w * e.reshape(-1)))
    h, j = measurement_model_pose(poses, np.broadcast_to(x, (len(z), 4)))[::2]
    e = z - h
    e[:, 1] = wrap_angle(e[:, 1])
    j = j.reshape(-1, 4)
    cinv = np.linalg.pinv(j.T @ (w[:, None] * j), rcond=1e-10, hermitian=True)
    lev = np.einsum("ij,jk,ik->i", j, cinv, j) * w
    return e, lev.reshape(-1, 3)
