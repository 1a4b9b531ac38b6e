"""The one-frame fusion problem without a solver (docs/CONVENTIONS.md, "One-shot fusion").

Everything :mod:`mmsnap_graph.fusion.solvers.gtsam_graph` (GTSAM) and
:mod:`mmsnap_graph.fusion.solvers.vectorized` (numpy) share, with no GTSAM import:

- validation at the public boundary: :func:`validate_frame` (with
  :func:`check_poses`, :func:`check_observed`), :func:`check_noise`,
  :func:`check_node_noise` (one noise or one per node, docs/CONVENTIONS.md,
  "Per-node noise"), :func:`check_pose_covariances` (docs/CONVENTIONS.md,
  "Calibration-aware fusion"), :func:`check_prior`, :func:`check_initial_state`;
- initial states (docs/CONVENTIONS.md, "Initial values"): :func:`initial_state`
  (one frame, validated), :func:`initial_states` (``F`` frames, vectorized),
  :func:`frame_initial_state` (one validated frame in plain floats, the
  per-frame hot path) and :func:`checked_initial_state`;
- the velocity degeneracy indicator :func:`velocity_degeneracy` (the geometry's
  condition number, ``FusionResult.degeneracy``) and :func:`condition_2x2`
  (their home is :mod:`mmsnap_graph.fusion.degeneracy`).
"""

from __future__ import annotations

import math
from typing import Mapping, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from factors.models import MEASUREMENT_NAMES, detection_to_global, detection_to_local_scalar

from ..errors import GeometryError, ValidationError
from .._validation import as_float_array, check_finite, check_heading, frozen_vector
from ..data.noise import GaussianPrior, MeasurementNoise
from .degeneracy import condition_2x2, velocity_degeneracy

__all__ = [
    "check_poses",
    "check_observed",
    "check_noise",
    "check_node_noise",
    "node_sigmas",
    "check_pose_covariances",
    "check_prior",
    "check_initial_state",
    "validate_frame",
    "validate_frames",
    "valid_rows",
    "initial_state",
    "initial_states",
    "frame_initial_state",
    "checked_initial_state",
    "condition_2x2",
    "velocity_degeneracy",
]

#: An initial position closer than this to a node is "at the node": its line
#: of sight (and the model's Jacobian) is undefined to rounding.
AT_NODE_M = 1e-9


# ---------------------------------------------------------------------------
# Validation


def check_noise(noise: object) -> MeasurementNoise:
    """``noise`` if it is a :class:`MeasurementNoise`; ValidationError otherwise."""
    if not isinstance(noise, MeasurementNoise):
        raise ValidationError(f"noise must be a MeasurementNoise, got {type(noise).__name__}")
    values = (noise.range_m, noise.omega_rad, noise.doppler_mps)
    if not all(SIGMA_MIN <= v <= SIGMA_MAX for v in values):
        _check_sigma_range(values, "noise")
    return noise


def check_node_noise(
    noise: object, n_nodes: int, node_names: Sequence[str] | None = None
) -> tuple[MeasurementNoise, ...]:
    """The measurement noise of each of ``n_nodes`` nodes, as a tuple of N
    :class:`MeasurementNoise` (docs/CONVENTIONS.md, "Per-node noise").

    ``noise`` is one :class:`MeasurementNoise` (every node), a sequence of N
    of them (one per node, in the order of the node poses) or, when
    ``node_names`` is given, a mapping ``{node name: MeasurementNoise}``
    holding every node. Raises ValidationError naming the field (``noise``,
    ``noise[i]`` or ``noise['name']``) and the value otherwise.
    """
    if isinstance(noise, MeasurementNoise):
        return (check_noise(noise),) * n_nodes
    if isinstance(noise, Mapping):
        if node_names is None:
            raise ValidationError(
                "noise must be a MeasurementNoise or a sequence of one MeasurementNoise per "
                "node, got a mapping (a mapping by node name is for fuse_recording)")
        missing = [name for name in node_names if name not in noise]
        if missing:
            raise ValidationError(
                f"noise has no MeasurementNoise for node {missing[0]!r} (it has {sorted(noise)}); "
                "a per-node noise mapping needs every fused node")
        items = [(f"noise[{name!r}]", noise[name]) for name in node_names]
    elif isinstance(noise, (list, tuple)) and any(isinstance(m, MeasurementNoise) for m in noise):
        if len(noise) != n_nodes:
            raise ValidationError(
                f"noise must hold one MeasurementNoise per node ({n_nodes}), got {len(noise)}")
        items = [(f"noise[{i}]", item) for i, item in enumerate(noise)]
    else:
        raise ValidationError(
            f"noise must be a MeasurementNoise, got {type(noise).__name__} {noise!r} (per-node "
            f"noise: a sequence of one MeasurementNoise per node, {n_nodes} here)")
    out = []
    for field_name, item in items:
        if not isinstance(item, MeasurementNoise):
            raise ValidationError(
                f"{field_name} must be a MeasurementNoise, got {type(item).__name__}")
        values = (item.range_m, item.omega_rad, item.doppler_mps)
        if not all(SIGMA_MIN <= v <= SIGMA_MAX for v in values):
            _check_sigma_range(values, field_name)
        out.append(item)
    return tuple(out)


def node_sigmas(noises: Sequence[MeasurementNoise]) -> NDArray:
    """(N, 3) float: each node's ``(range_m, omega_rad, doppler_mps)`` sigmas."""
    return np.array([(m.range_m, m.omega_rad, m.doppler_mps) for m in noises], dtype=float)


def check_pose_covariances(
    pose_covariances: object, n_nodes: int, node_names: Sequence[str] | None = None
) -> NDArray | None:
    """Node pose covariances in the Pose2 body tangent (docs/CONVENTIONS.md,
    "Calibration-aware fusion"): ``(N, 3, 3)`` float or, when ``node_names``
    is given, a mapping ``{node name: (3, 3)}`` (a node left out, or None: an
    exact pose).

    Returns None when ``pose_covariances`` is None or every pose is exact;
    otherwise an (N, 3, 3) read-only array where an exact pose (a matrix
    that is all NaN or all zero) holds NaN. Every other matrix must be
    finite, symmetric and positive definite; ValidationError naming the entry
    (``pose_covariances[i]`` or ``pose_covariances['name']``) otherwise.
    """
    if pose_covariances is None:
        return None
    if isinstance(pose_covariances, Mapping) and node_names is not None:
        try:
            return check_pose_covariances(_by_name(pose_covariances, node_names), n_nodes)
        except ValidationError as exc:  # name the node, not its index
            message = str(exc)
            for i, name in enumerate(node_names):
                message = message.replace(f"pose_covariances[{i}]", f"pose_covariances[{name!r}]")
            raise ValidationError(message) from None
    cov = np.array(as_float_array(pose_covariances, "pose_covariances"), dtype=float)
    if cov.shape != (n_nodes, 3, 3):
        raise ValidationError(
            f"pose_covariances must have shape ({n_nodes}, 3, 3) (one Pose2 covariance per "
            f"node), got {cov.shape}")
    exact = np.isnan(cov).all(axis=(1, 2)) | (cov == 0.0).all(axis=(1, 2))
    for i in np.flatnonzero(~exact):
        c = cov[i]
        if not np.isfinite(c).all():
            raise ValidationError(
                f"pose_covariances[{i}] must be finite (or all NaN for an exact pose), "
                f"got {c.tolist()}")
        if not np.allclose(c, c.T, rtol=1e-9, atol=1e-300):
            raise ValidationError(f"pose_covariances[{i}] must be symmetric, got {c.tolist()}")
        if np.linalg.eigvalsh(c)[0] <= 0.0:
            raise ValidationError(
                f"pose_covariances[{i}] must be positive definite (or all NaN / all zero for "
                f"an exact pose), got {c.tolist()}")
    if exact.all():
        return None
    cov[exact] = np.nan
    cov.setflags(write=False)
    return cov


def check_prior(prior: object) -> GaussianPrior | None:
    """``prior`` if it is a :class:`GaussianPrior` or None (ML); ValidationError otherwise."""
    if prior is not None and not isinstance(prior, GaussianPrior):
        raise ValidationError(
            f"prior must be a GaussianPrior or None, got {type(prior).__name__}"
        )
    if prior is not None:
        values = prior.sigmas.tolist()  # (the mean is finite: GaussianPrior checks it)
        if not all(SIGMA_MIN <= v <= SIGMA_MAX for v in values):
            _check_sigma_range(values, "prior")
    return prior


def check_poses(node_poses: ArrayLike) -> NDArray:
    """(N, 3) float node poses, N >= 1, finite; raises ValidationError otherwise."""
    poses = as_float_array(node_poses, "node_poses")
    if poses.ndim != 2 or poses.shape[1] != 3:
        raise ValidationError(f"node_poses must have shape (N, 3), got {poses.shape}")
    if poses.shape[0] == 0:
        raise ValidationError("node_poses must hold at least one node, got shape (0, 3)")
    if not _all_finite(poses):
        check_finite(poses, "node_poses")
    if np.abs(poses[:, 2]).max() > 2.0 * np.pi + 1e-9:
        i = int(np.argmax(np.abs(poses[:, 2])))
        check_heading(float(poses[i, 2]), f"node_poses[{i}]")
    return poses


def _by_name(pose_covariances: Mapping, node_names: Sequence[str]) -> NDArray:
    """(N, 3, 3) in node order from a mapping by name (NaN for a node left out)."""
    out = np.full((len(node_names), 3, 3), np.nan)
    for i, name in enumerate(node_names):
        if pose_covariances.get(name) is not None:
            c = as_float_array(pose_covariances[name], f"pose_covariances[{name!r}]")
            if c.shape != (3, 3):
                raise ValidationError(
                    f"pose_covariances[{name!r}] must have shape (3, 3), got {c.shape}")
            out[i] = c
    return out


def _all_finite(arr: NDArray) -> bool:
    # Plain floats beat numpy's temporaries for the few numbers of one frame.
    if arr.size <= 64:
        return all(map(math.isfinite, arr.ravel().tolist()))
    return bool(np.isfinite(arr).all())


def check_observed(observed: ArrayLike | None, n_nodes: int) -> NDArray | None:
    """(N,) bool observed flags, or None when every node observed (or None given)."""
    if observed is None:
        return None
    obs = np.asarray(observed)
    if obs.dtype != bool:
        raise ValidationError(f"observed must be a boolean array, got dtype {obs.dtype}")
    if obs.shape != (n_nodes,):
        raise ValidationError(
            f"observed must have shape ({n_nodes},) (one flag per node), got {obs.shape}"
        )
    return None if obs.all() else obs


def _check_measurement_rows(z: NDArray, rows: NDArray) -> None:
    """Detailed errors for the observed measurement rows (slow path)."""
    for i in rows:
        for j, name in enumerate(MEASUREMENT_NAMES):
            value = float(z[i, j])
            if not math.isfinite(value):
                raise ValidationError(
                    f"measurements[{i}, {j}] ({name} of node {i}) must be finite, got {value!r}"
                )
        rng_m, omega = float(z[i, 0]), float(z[i, 1])
        if rng_m < 0.0:
            raise ValidationError(
                f"measurements[{i}, 0] (range_m of node {i}) must be >= 0, got {rng_m!r}"
            )
        if rng_m == 0.0:
            raise GeometryError(
                f"measurements[{i}, 0] (range_m of node {i}) is 0: the target would sit at "
                "the node's position, where the measurement model is undefined"
            )
        if abs(omega) > np.pi:
            raise ValidationError(
                f"measurements[{i}, 1] (omega_rad of node {i}) must be in [-pi, pi], "
                f"got {omega!r}"
            )


def _nan_rows_unobserved(z: NDArray) -> NDArray | None:
    """The observed flags of the missing-data convention: a row that is all NaN
    is "not observed"; None when every row holds a number."""
    zl = z.tolist()
    missing = [r != r and w != w and v != v for r, w, v in zl] if len(zl) <= 16 else (
        np.isnan(z).all(axis=1).tolist())
    if not any(missing):
        return None
    return ~np.array(missing, dtype=bool)


def validate_frame(
    node_poses: ArrayLike, measurements: ArrayLike, observed: ArrayLike | None = None
) -> tuple[NDArray, NDArray, NDArray | None]:
    """Check one frame's inputs; return ``(poses (N, 3), measurements (N, 3),
    observed (N,) bool or None when every node observed)``.

    The missing-data convention (docs/CONVENTIONS.md): without ``observed``, a
    measurement row that is all NaN means "this node did not observe the
    target"; with ``observed``, the mask decides and its unobserved rows may
    hold anything (NaN included), its observed rows must be valid. Both give
    the same result. Observed rows need ``0 < range < inf``,
    ``|omega| <= pi`` and a finite Doppler.

    Raises :class:`~mmsnap_graph.errors.ValidationError` naming the field and
    value for wrong shapes, NaN or inf in an observed row, a negative range or
    ``|omega| > pi``; :class:`~mmsnap_graph.errors.GeometryError` for a zero
    range (a target at a node).
    """
    poses = check_poses(node_poses)
    n_nodes = poses.shape[0]
    z = as_float_array(measurements, "measurements")
    if z.shape != (n_nodes, 3):
        raise ValidationError(
            f"measurements must have shape ({n_nodes}, 3) (one (range_m, omega_rad, "
            f"doppler_mps) row per node), got {z.shape}"
        )
    obs = check_observed(observed, n_nodes)
    if observed is None:
        obs = _nan_rows_unobserved(z)
    # Fast path: one pass of float comparisons (False for NaN); the detailed
    # message only on failure.
    if n_nodes <= 16:
        flags = [True] * n_nodes if obs is None else obs.tolist()
        ok = all(
            0.0 < r < math.inf and -math.pi <= w <= math.pi and -math.inf < v < math.inf
            for (r, w, v), f in zip(z.tolist(), flags)
            if f
        )
    else:
        zo = z if obs is None else z[obs]
        ok = bool(
            np.isfinite(zo).all() and (zo[:, 0] > 0.0).all() and (np.abs(zo[:, 1]) <= np.pi).all()
        )
    if not ok:
        rows = np.arange(n_nodes) if obs is None else np.flatnonzero(obs)
        _check_measurement_rows(z, rows)
    return poses, z, obs


def validate_frames(
    node_poses: ArrayLike, measurements: ArrayLike, observed: ArrayLike | None = None
) -> tuple[NDArray, NDArray, NDArray]:
    """:func:`validate_frame` for ``F`` frames: ``(poses (N, 3) or (F, N, 3),
    measurements (F, N, 3), observed (F, N) bool)``.

    The same convention and checks as :func:`validate_frame`: without
    ``observed`` an all-NaN row is not observed; observed rows need
    ``0 < range < inf``, ``|omega| <= pi`` and a finite Doppler; unobserved
    rows may hold anything and come back as zeros (the returned measurements
    are a copy then). Raises ValidationError naming the first offending entry
    (GeometryError for a zero range, as :func:`validate_frame`).
    """
    z = as_float_array(measurements, "measurements")
    if z.ndim != 3 or z.shape[-1] != 3:
        raise ValidationError(f"measurements must have shape (F, N, 3), got {z.shape}")
    n_frames, n_nodes = z.shape[:2]
    poses = as_float_array(node_poses, "node_poses")
    if poses.shape not in ((n_nodes, 3), (n_frames, n_nodes, 3)):
        raise ValidationError(
            f"node_poses must have shape ({n_nodes}, 3) or ({n_frames}, {n_nodes}, 3), "
            f"got {poses.shape}"
        )
    check_finite(poses, "node_poses")
    if observed is None:
        obs = ~np.isnan(z).all(axis=2)
    else:
        obs = np.asarray(observed)
        if obs.shape != (n_frames, n_nodes) or obs.dtype != bool:
            raise ValidationError(
                f"observed must be a bool array of shape ({n_frames}, {n_nodes}), "
                f"got {obs.dtype} {obs.shape}"
            )
    bad = ~valid_rows(z) & obs
    if bad.any():
        f, n = np.argwhere(bad)[0]
        try:
            _check_measurement_rows(z[f], [int(n)])
        except (ValidationError, GeometryError) as exc:
            msg = str(exc).replace("measurements[", f"measurements[{f}, ", 1)
            raise type(exc)(f"measurements must be finite and in range in observed rows "
                            f"(frame {f}): {msg}") from None
    if not obs.all():
        z = np.where(obs[..., None], z, 0.0)
    return poses, z, obs


def valid_rows(z: NDArray) -> NDArray:
    """(..., N) bool: which measurement rows ``(..., N, 3)`` are valid
    observations (``0 < range < inf``, ``|omega| <= pi``, finite Doppler)."""
    with np.errstate(invalid="ignore"):
        return ((z[..., 0] > 0.0) & (z[..., 0] < np.inf) & (np.abs(z[..., 1]) <= np.pi)
                & np.isfinite(z[..., 2]))


#: Sigmas (noise and prior) must lie in ``[SIGMA_MIN, SIGMA_MAX]``: squared
#: ratios of such sigmas stay finite in double precision.
SIGMA_MIN, SIGMA_MAX = 1e-60, 1e60


def _check_sigma_range(sigmas, what: str) -> None:
    values = [float(s) for s in np.ravel(sigmas)]
    if not all(SIGMA_MIN <= s <= SIGMA_MAX for s in values):
        raise ValidationError(
            f"{what} sigmas must be in [{SIGMA_MIN:g}, {SIGMA_MAX:g}], got {values}"
        )


# ---------------------------------------------------------------------------
# Initial values


def initial_states(
    node_poses: ArrayLike,
    measurements: ArrayLike,
    observed: ArrayLike | None = None,
    prior: GaussianPrior | None = GaussianPrior(),
    *,
    noise: MeasurementNoise | Sequence[MeasurementNoise] = MeasurementNoise(),
) -> NDArray:
    """Initial values of docs/CONVENTIONS.md for ``F`` frames at once (no validation).

    node_poses : (N, 3) or (F, N, 3) float.
    measurements : (F, N, 3) float; rows of unobserved nodes may hold anything.
    observed : (F, N) bool or None (all observed).
    prior : the prior used as the velocity regularizer, or None.
    noise : sets the Doppler sigma that weighs the Doppler equations against
        the prior (default :class:`MeasurementNoise`); a sequence of N
        (per-node noise) weighs each node's Doppler equation by its own sigma.
    Returns (F, 4) float.

    Position: the average of the observed nodes' own detections mapped to the
    global frame (docs/CONVENTIONS.md, the corrected eq. 19). Velocity: the least-squares
    solution of ``V_i = u_i^T v`` with ``u_i`` the line of sight from node i to
    that position, regularized by the prior's velocity part; without a prior
    and with parallel lines of sight (or one node) the minimum-norm solution,
    i.e. the observable radial part only. A frame without observations starts
    at the prior mean (NaN without a prior). A frame whose initial position
    is within 1 nm of an observed node's gets a NaN velocity (its line of
    sight is undefined).
    """
    poses = np.asarray(node_poses, dtype=float)
    z = np.asarray(measurements, dtype=float)
    n_frames, n_nodes = z.shape[:2]
    if observed is None:
        w = np.ones((n_frames, n_nodes))
    else:
        w = np.asarray(observed, dtype=bool).astype(float)
    rng_m = np.where(w > 0, z[..., 0], 0.0)
    omega = np.where(w > 0, z[..., 1], 0.0)
    dop = np.where(w > 0, z[..., 2], 0.0)
    n_obs = w.sum(axis=1)
    det = detection_to_global(rng_m, omega, poses)  # (F, N, 2)
    with np.errstate(invalid="ignore", divide="ignore"):
        pos = np.sum(det * w[..., None], axis=1) / n_obs[:, None]
    node_xy = poses[..., :2]
    d = pos[:, None, :] - node_xy
    dist = np.linalg.norm(d, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        u = np.where(dist < AT_NODE_M, np.nan, d / dist)
    u = np.where(w[..., None] > 0, u, 0.0)
    # Normal equations of the weighted linear problem (2x2 per frame).
    # Weighted by sigma_V^2 so only the ratio to the prior's sigmas matters.
    doppler_sigma, dw = _doppler_weights(noise)
    wd = w if dw is None else w * np.asarray(dw)
    a = np.einsum("fn,fni,fnj->fij", wd, u, u)
    b = np.einsum("fn,fni,fn->fi", wd, u, dop)
    if prior is not None:
        reg = (doppler_sigma / prior.sigmas[2:]) ** 2
        a = a + np.diag(reg)
        b = b + reg * prior.mean[2:]
    vel = _solve_2x2_min_norm(a, b)
    state = np.concatenate([pos, vel], axis=1)
    if prior is not None:
        empty = n_obs == 0
        state[empty] = prior.mean
    return state


def _doppler_weights(noise) -> tuple[float, list[float] | None]:
    """``(reference Doppler sigma, per-node weights or None)``: the Doppler
    equations of the initial velocity weighted by ``(ref / sigma_i)^2``, the
    reference the first node's sigma (all weights exactly 1 for equal sigmas,
    so one noise and N equal ones give the same numbers)."""
    if isinstance(noise, MeasurementNoise):
        return noise.doppler_mps, None
    sd = [m.doppler_mps for m in noise]
    ref = sd[0]
    return ref, [(ref / s) ** 2 for s in sd]


def _solve_2x2_min_norm(a: NDArray, b: NDArray) -> NDArray:
    """Minimum-norm solutions of symmetric PSD 2x2 systems, (F, 2, 2) and (F, 2).

    Closed-form eigenvalues, the same formula as :func:`frame_initial_state`
    (``np.linalg.eigh`` on 2x2 blocks cost the batch solver ~0.85 us/frame).
    """
    a11, a12, a22 = a[:, 0, 0], a[:, 0, 1], a[:, 1, 1]
    b1, b2 = b[:, 0], b[:, 1]
    half_tr = 0.5 * (a11 + a22)
    disc = np.sqrt(0.25 * (a11 - a22) ** 2 + a12 * a12)
    hi = half_tr + disc
    lo = half_tr - disc
    tol = 1e-10 * np.maximum(hi, 1e-300)
    det = a11 * a22 - a12 * a12
    out = np.zeros_like(b)
    with np.errstate(divide="ignore", invalid="ignore"):
        full = lo > tol
        out[:, 0] = np.where(full, (a22 * b1 - a12 * b2) / det, 0.0)
        out[:, 1] = np.where(full, (a11 * b2 - a12 * b1) / det, 0.0)
        # Rank one: project onto the eigenvector of the large eigenvalue.
        rank1 = ~full & (hi > tol)
        if np.any(rank1):
            first = np.abs(hi - a11) >= np.abs(hi - a22)
            e1 = np.where(first, a12, hi - a22)
            e2 = np.where(first, hi - a11, a12)
            norm = np.hypot(e1, e2)
            axis_x = a11 >= a22
            e1 = np.where(norm == 0.0, axis_x.astype(float), e1 / norm)
            e2 = np.where(norm == 0.0, (~axis_x).astype(float), e2 / norm)
            k = (e1 * b1 + e2 * b2) / hi
            out[:, 0] = np.where(rank1, k * e1, out[:, 0])
            out[:, 1] = np.where(rank1, k * e2, out[:, 1])
    bad = ~np.all(np.isfinite(a), axis=(1, 2)) | ~np.all(np.isfinite(b), axis=1)
    out[bad] = np.nan
    return out


def frame_initial_state(
    poses: NDArray, z: NDArray, obs: NDArray | None, prior: GaussianPrior | None,
    noise: MeasurementNoise | Sequence[MeasurementNoise] = MeasurementNoise(),
) -> list[float]:
    """:func:`initial_states` for one validated frame, in plain floats (the
    per-frame hot path; the tests check it against the vectorized form).

    poses : (N, 3); z : (N, 3); obs : (N,) bool or None (all observed).
    Returns ``[x_m, y_m, vx_mps, vy_mps]``; NaN velocity when the position is
    on an observed node, all NaN without observations and without a prior.
    """
    pl = poses.tolist()
    zl = z.tolist()
    nodes = [i for i in range(len(pl)) if obs is None or obs[i]]
    if not nodes:
        return prior.mean.tolist() if prior is not None else [math.nan] * 4
    sx = sy = 0.0
    for i in nodes:
        px, py, phi = pl[i]
        rng_m, omega = zl[i][0], zl[i][1]
        u, v = detection_to_local_scalar(rng_m, omega)
        c, s = math.cos(phi), math.sin(phi)
        sx += px + u * c - v * s
        sy += py + u * s + v * c
    x = sx / len(nodes)
    y = sy / len(nodes)
    a11 = a12 = a22 = b1 = b2 = 0.0
    sd, dw = _doppler_weights(noise)
    for i in nodes:
        dx = x - pl[i][0]
        dy = y - pl[i][1]
        r = math.sqrt(dx * dx + dy * dy)
        if r < AT_NODE_M:
            return [x, y, math.nan, math.nan]
        ux, uy = dx / r, dy / r
        if dw is not None:
            wi = dw[i]
            ux, uy = ux * math.sqrt(wi), uy * math.sqrt(wi)
            zd = zl[i][2] * math.sqrt(wi)
        else:
            zd = zl[i][2]
        a11 += ux * ux
        a12 += ux * uy
        a22 += uy * uy
        b1 += ux * zd
        b2 += uy * zd
    if prior is not None:
        m = prior.mean.tolist()
        ps = prior.sigmas.tolist()
        r1 = (sd / ps[2]) ** 2
        r2 = (sd / ps[3]) ** 2
        a11 += r1
        a22 += r2
        b1 += r1 * m[2]
        b2 += r2 * m[3]
    # Minimum-norm solution of the symmetric 2x2 system (as _solve_2x2_min_norm).
    half_tr = 0.5 * (a11 + a22)
    disc = math.sqrt(0.25 * (a11 - a22) ** 2 + a12 * a12)
    hi = half_tr + disc
    lo = half_tr - disc
    tol = 1e-10 * max(hi, 1e-300)
    if lo > tol:
        det = a11 * a22 - a12 * a12
        return [x, y, (a22 * b1 - a12 * b2) / det, (a11 * b2 - a12 * b1) / det]
    if hi <= tol:
        return [x, y, 0.0, 0.0]
    # Rank one: project onto the eigenvector of the large eigenvalue.
    e1, e2 = (a12, hi - a11) if abs(hi - a11) >= abs(hi - a22) else (hi - a22, a12)
    norm = math.hypot(e1, e2)
    if norm == 0.0:  # diagonal matrix: the eigenvector is an axis
        e1, e2 = (1.0, 0.0) if a11 >= a22 else (0.0, 1.0)
    else:
        e1, e2 = e1 / norm, e2 / norm
    k = (e1 * b1 + e2 * b2) / hi
    return [x, y, k * e1, k * e2]


def check_initial_state(initial_state: ArrayLike, poses: NDArray, obs: NDArray | None) -> NDArray:
    """A user-given starting state, (4,) read-only; raises GeometryError when
    its position is on an observed node."""
    x0 = frozen_vector(initial_state, "initial_state", 4)
    for i, (px, py, _) in enumerate(poses.tolist()):
        if (obs is None or obs[i]) and math.hypot(x0[0] - px, x0[1] - py) < AT_NODE_M:
            raise GeometryError(
                f"initial_state position {x0[:2].tolist()} is at node {i}'s position, where the "
                "measurement model is undefined"
            )
    return x0


def checked_initial_state(
    poses: NDArray, z: NDArray, obs: NDArray | None, prior: GaussianPrior | None,
    noise: MeasurementNoise | Sequence[MeasurementNoise] = MeasurementNoise(),
) -> NDArray:
    """:func:`frame_initial_state` as a (4,) array; raises GeometryError when it
    is not finite (the average detection on a node)."""
    x0_list = frame_initial_state(poses, z, obs, prior, noise)
    x0 = np.array(x0_list)
    if not all(map(math.isfinite, x0_list)):
        raise GeometryError(
            f"initial position {x0[:2].tolist()} (the average of the nodes' detections) "
            "coincides with a node's position, where the lines of sight are undefined"
        )
    return x0


def initial_state(
    node_poses: ArrayLike,
    measurements: ArrayLike,
    observed: ArrayLike | None = None,
    prior: GaussianPrior | None = GaussianPrior(),
    *,
    noise: MeasurementNoise | Sequence[MeasurementNoise] = MeasurementNoise(),
) -> NDArray:
    """Initial state of one frame (docs/CONVENTIONS.md, "Initial values"); (4,) float.

    node_poses : (N, 3) float, ``(x_m, y_m, phi_rad)``.
    measurements : (N, 3) float, ``(range_m, omega_rad, doppler_mps)``.
    observed : (N,) bool or None (all observed).
    prior : :class:`GaussianPrior` regularizing the velocity, or None.
    noise : :class:`MeasurementNoise` (its Doppler sigma weighs the prior), or
        one per node (each Doppler equation weighted by its own sigma).

    Raises :class:`~mmsnap_graph.errors.GeometryError` when the average
    detection lands on a node's position (its line of sight is undefined).
    See :func:`initial_states` for the formulas.
    """
    poses, z, obs = validate_frame(node_poses, measurements, observed)
    if (obs is not None and not obs.any()) and prior is None:
        raise ValidationError("observed has no True entry and there is no prior: nothing to start from")
    return checked_initial_state(poses, z, obs, prior, noise)
