"""The one-frame fusion problem without a solver (docs/CONVENTIONS.md, "One-shot fusion").

Everything :mod:`mmsnap_graph.fusion.solvers.gtsam_graph` (GTSAM) and
:mod:`mmsnap_graph.fusion.solvers.vectorized` (numpy) share, with no GTSAM import:

- validation at the public boundary: :func:`validate_frame` (with
  :func:`check_poses`, :func:`check_observed`), :func:`check_noise`,
  :func:`check_node_noise` (one noise or one per node, docs/CONVENTIONS.md,
  "Per-node noise"), :func:`check_pose_covariances` (docs/CONVENTIONS.md,
  "Calibration-aware fusion"), :func:`check_prior`;
- (the initial state, docs/CONVENTIONS.md "Initial values", is
  :func:`mmsnap_graph.fusion.frame_problem.initial_states`, of a
  :class:`~mmsnap_graph.fusion.frame_problem.FrameProblem` made with these
  checks);
- the velocity degeneracy indicator :func:`velocity_degeneracy` (the geometry's
  condition number, ``FusionSolution.degeneracy``) and :func:`condition_2x2`
  (their home is :mod:`mmsnap_graph.fusion.degeneracy`).
"""

from __future__ import annotations

import math
from typing import Mapping, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from factors.models import MEASUREMENT_NAMES

from ..errors import GeometryError, ValidationError
from .._validation import as_float_array, check_finite, check_heading
from ..data.noise import GaussianPrior, MeasurementNoise
from .degeneracy import condition_2x2, velocity_degeneracy

__all__ = [
    "check_poses",
    "check_observed",
    "check_noise",
    "check_node_noise",
    "NodeNoise",
    "node_sigmas",
    "check_pose_covariances",
    "check_prior",
    "validate_frame",
    "validate_frames",
    "valid_rows",
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


class NodeNoise(tuple):
    """N :class:`MeasurementNoise`, one per node in node order, as
    :func:`check_node_noise` validated them: handed on, they are not
    checked again."""

    __slots__ = ()


def check_node_noise(
    noise: object, n_nodes: int, node_names: Sequence[str] | None = None
) -> NodeNoise:
    """The measurement noise of each of ``n_nodes`` nodes, as a
    :class:`NodeNoise` (a tuple of N :class:`MeasurementNoise`,
    docs/CONVENTIONS.md, "Per-node noise"); a :class:`NodeNoise` of N nodes
    is returned as it is (validated once).

    ``noise`` is one :class:`MeasurementNoise` (every node), a sequence of N
    of them (one per node, in the order of the node poses) or, when
    ``node_names`` is given, a mapping ``{node name: MeasurementNoise}``
    holding every node. Raises ValidationError naming the field (``noise``,
    ``noise[i]`` or ``noise['name']``) and the value otherwise.
    """
    if type(noise) is NodeNoise and len(noise) == n_nodes:
        return noise
    if isinstance(noise, MeasurementNoise):
        return NodeNoise((check_noise(noise),) * n_nodes)
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
    return NodeNoise(out)


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
    if poses.size <= 64:  # one frame's few numbers: plain floats beat numpy's temporaries
        values = poses.ravel().tolist()
        if not all(map(math.isfinite, values)):
            check_finite(poses, "node_poses")
        beyond = max(map(abs, values[2::3])) > 2.0 * math.pi + 1e-9
    else:
        if not bool(np.isfinite(poses).all()):
            check_finite(poses, "node_poses")
        beyond = np.abs(poses[:, 2]).max() > 2.0 * np.pi + 1e-9
    if beyond:
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
