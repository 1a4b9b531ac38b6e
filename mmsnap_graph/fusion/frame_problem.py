"""The one-shot fusion problem as a value: :class:`FrameProblem`
(docs/CONVENTIONS.md, "One-shot fusion"), and its one initial state
(:func:`initial_states`). GTSAM-free.

A :class:`FrameProblem` holds ``F`` frames of ``N`` nodes: the node poses,
their covariances, each frame's measurements and observed mask, each node's
noise, the prior (None: maximum likelihood), optionally the starting states and
a robust kernel. It is validated once, when made; the problems derived from it
(:meth:`FrameProblem.__getitem__`, :meth:`~FrameProblem.with_observed`,
:meth:`~FrameProblem.with_initial_state`, :meth:`~FrameProblem.with_kernel`,
:meth:`~FrameProblem.with_frames`) check only what they change. Every solver
of :func:`mmsnap_graph.fusion.solve.solve` takes it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from factors.models import (detection_to_global, detection_to_local_scalar, predict_measurements,
                            wrap_angle)

from .._validation import as_float_array
from ..data.noise import GaussianPrior, MeasurementNoise
from ..errors import GeometryError, ValidationError
from .problem import (AT_NODE_M, check_node_noise, check_poses, check_pose_covariances,
                      check_prior, node_sigmas, validate_frame, validate_frames)

__all__ = ["FrameProblem", "initial_states", "initial_state_floats", "whitened_residuals",
           "SMALL_PROBLEM_ROWS"]

#: Frames made with :meth:`FrameProblem.with_frames` of at most this many
#: measurement rows (frames times nodes) are validated in plain floats
#: (numpy's per-call overhead dominates below it).
SMALL_PROBLEM_ROWS = 48


def _check_kernel(kernel: object) -> tuple[str, float] | None:
    if kernel is None:
        return None
    if (not isinstance(kernel, tuple) or len(kernel) != 2 or kernel[0] not in ("huber", "cauchy")
            or isinstance(kernel[1], bool) or not isinstance(kernel[1], (int, float))
            or not (math.isfinite(kernel[1]) and kernel[1] > 0)):
        raise ValidationError(f"kernel must be None or ('huber' | 'cauchy', k > 0), got {kernel!r}")
    return (kernel[0], float(kernel[1]))


def _frozen(arr: NDArray) -> NDArray:
    if arr.flags.writeable:
        arr = arr.copy() if not arr.flags.owndata else arr
        arr.setflags(write=False)
    return arr


@dataclass(frozen=True, kw_only=True, slots=True, eq=False)
class FrameProblem:
    """``F`` frames of the one-shot problem of ``N`` nodes, validated once.

    poses : (N, 3) float, ``(x_m, y_m, phi_rad)`` of each node (or (F, N, 3),
        one network per frame).
    measurements : (F, N, 3) float, ``(range_m, omega_rad, doppler_mps)``
        (a single frame may be given as (N, 3)); the missing-data convention
        of :func:`~mmsnap_graph.fusion.problem.validate_frames`: without
        ``observed`` an all-NaN row is "not observed"; unobserved rows are
        stored as zeros.
    observed : (F, N) bool or None (the rows that are not all NaN).
    noise : a :class:`MeasurementNoise` (every node) or N of them (node
        order); stored as a tuple of N.
    prior : :class:`GaussianPrior` (MAP, default the paper's) or None (ML).
    pose_covariances : (N, 3, 3) each pose's covariance in the Pose2 body
        tangent, all NaN (or zero) for an exact pose; None: exact poses.
    initial_state : (F, 4) where the solvers start; None: :func:`initial_states`.
    kernel : ``("huber" | "cauchy", k)``: the robust kernel on each node's
        whitened residual 3-vector (the cost the solvers minimize); None:
        least squares. :func:`~mmsnap_graph.fusion.solve.robust_solve` sets it.

    Raises ValidationError (GeometryError for a zero range, or a given
    starting position on an observed node) naming the field and value.
    """

    poses: NDArray
    measurements: NDArray
    observed: NDArray | None = None
    noise: MeasurementNoise | Sequence[MeasurementNoise] = MeasurementNoise()
    prior: GaussianPrior | None = field(default_factory=GaussianPrior)
    pose_covariances: NDArray | None = None
    initial_state: NDArray | None = None
    kernel: tuple[str, float] | None = None
    _cache: dict = field(default_factory=dict, repr=False, init=False)

    def __post_init__(self) -> None:
        z = as_float_array(self.measurements, "measurements")
        if z.ndim == 2:  # one frame: its own messages (no frame index)
            poses, z, obs = validate_frame(self.poses, z, self.observed)
            n_nodes = z.shape[0]
            # Copies of the frame's own (N, 3) and (1, N) arrays, unobserved
            # rows zero (the per-frame path: one copy each).
            if obs is None:
                z, obs = z.reshape(1, n_nodes, 3).copy(), np.ones((1, n_nodes), dtype=bool)
            else:
                z, obs = np.where(obs[None, :, None], z[None], 0.0), obs.reshape(1, n_nodes).copy()
        else:
            poses = as_float_array(self.poses, "node_poses")
            if poses.ndim == 2:
                poses = check_poses(poses)
            poses, z, obs = validate_frames(poses, z, self.observed)
            n_nodes = z.shape[1]
            z, obs = np.array(z, dtype=float), np.array(obs, dtype=bool)
        check_prior(self.prior)
        noise = check_node_noise(self.noise, n_nodes)
        pose_cov = check_pose_covariances(self.pose_covariances, n_nodes)
        set_ = object.__setattr__
        z.setflags(write=False)
        obs.setflags(write=False)
        set_(self, "poses", _frozen(np.array(poses, dtype=float)))
        set_(self, "measurements", z)
        set_(self, "observed", obs)
        set_(self, "noise", noise)
        set_(self, "pose_covariances", pose_cov)
        set_(self, "kernel", _check_kernel(self.kernel))
        set_(self, "initial_state", _check_start(self.initial_state, self.poses, self.observed))

    # ------------------------------------------------------------------
    @property
    def n_frames(self) -> int:
        """F, the frames."""
        return int(self.measurements.shape[0])

    @property
    def n_nodes(self) -> int:
        """N, the nodes."""
        return int(self.measurements.shape[1])

    def __len__(self) -> int:
        return self.n_frames

    @property
    def sigmas(self) -> NDArray:
        """(N, 3) each node's ``(range_m, omega_rad, doppler_mps)`` sigmas."""
        if "sigmas" not in self._cache:
            self._cache["sigmas"] = node_sigmas(self.noise)
        return self._cache["sigmas"]

    def cached(self, key, make):
        """The value ``make()`` computed once for this problem's network
        (shared by the problems derived from it), under ``key``."""
        try:
            return self._cache[key]
        except KeyError:
            value = self._cache[key] = make()
            return value

    @property
    def one_noise(self) -> bool:
        """True when every node has the same noise."""
        return self.noise.count(self.noise[0]) == len(self.noise)

    def _derived(self, **changes) -> "FrameProblem":
        """A problem sharing this one's validated parts (no validation)."""
        out = object.__new__(FrameProblem)
        set_ = object.__setattr__
        for name in _FIELDS:
            set_(out, name, changes[name] if name in changes else getattr(self, name))
        return out

    def __getitem__(self, index) -> "FrameProblem":
        """The frames ``index`` (an int, a slice, indices or a mask; an int
        keeps the frame axis) as a problem of their own."""
        if isinstance(index, (int, np.integer)):
            index = [int(index)]
        return self._derived(
            poses=self.poses[index] if self.poses.ndim == 3 else self.poses,
            measurements=self.measurements[index], observed=self.observed[index],
            initial_state=None if self.initial_state is None else self.initial_state[index])

    def with_observed(self, observed: ArrayLike) -> "FrameProblem":
        """The same frames with only the nodes of ``observed`` (F, N) bool
        (those it marks that this problem observes), from the initial values."""
        mask = np.asarray(observed, dtype=bool)
        if mask.shape != self.observed.shape:
            raise ValidationError(f"observed must have shape {self.observed.shape}, got "
                                  f"{mask.shape}")
        return self._derived(observed=_frozen(mask & self.observed), initial_state=None)

    def with_initial_state(self, initial_state: ArrayLike | None) -> "FrameProblem":
        """The same frames started at ``initial_state`` (F, 4) (None: the
        initial values)."""
        return self._derived(initial_state=_check_start(initial_state, self.poses, self.observed))

    def with_kernel(self, kernel: tuple[str, float] | None) -> "FrameProblem":
        """The same frames with the robust ``kernel`` ``(name, k)`` (or None)."""
        return self._derived(kernel=_check_kernel(kernel))

    def with_frames(self, measurements: ArrayLike, observed: ArrayLike | None = None
                    ) -> "FrameProblem":
        """Other frames of the same network (poses (N, 3), noise, prior,
        pose covariances, kernel): only the measurements are validated."""
        if self.poses.ndim == 3:
            raise ValidationError("with_frames needs one network for every frame (poses (N, 3))")
        z = measurements if type(measurements) is np.ndarray else as_float_array(
            measurements, "measurements")
        if z.ndim == 3 and observed is not None and z.size <= SMALL_PROBLEM_ROWS * 3 \
                and z.shape[1] == self.n_nodes:
            obs = np.asarray(observed)
            if obs.dtype == bool and obs.shape == z.shape[:2] and _rows_valid(z, obs):
                z = np.where(obs[..., None], z, 0.0) if not obs.all() else z.astype(float)
                return self._derived(measurements=_frozen(z), observed=_frozen(obs.copy()),
                                     initial_state=None)
        _, z, obs = validate_frames(self.poses, z, observed)
        return self._derived(measurements=_frozen(np.array(z, dtype=float)),
                             observed=_frozen(np.array(obs, dtype=bool)), initial_state=None)


_FIELDS = tuple(FrameProblem.__dataclass_fields__)


def _rows_valid(z: NDArray, obs: NDArray) -> bool:
    """Every observed row of a small ``z`` valid (one pass of float comparisons)."""
    for zf, of in zip(z.tolist(), obs.tolist()):
        for (r, w, v), o in zip(zf, of):
            if o and not (0.0 < r < math.inf and -math.pi <= w <= math.pi
                          and -math.inf < v < math.inf):
                return False
    return True


def _check_start(initial_state, poses: NDArray, observed: NDArray) -> NDArray | None:
    """A given (F, 4) start, finite and off every observed node; None stays None."""
    if initial_state is None:
        return None
    x0 = np.array(as_float_array(initial_state, "initial_state"), dtype=float)
    if x0.shape != (observed.shape[0], 4):
        raise ValidationError(f"initial_state must have shape ({observed.shape[0]}, 4), got "
                              f"{x0.shape}")
    if not np.isfinite(x0).all():
        f = int(np.flatnonzero(~np.isfinite(x0).all(axis=1))[0])
        raise ValidationError(f"initial_state[{f}] must be finite, got {x0[f].tolist()}")
    d = np.hypot(x0[:, None, 0] - poses[..., 0], x0[:, None, 1] - poses[..., 1])
    on_node = (d < AT_NODE_M) & observed
    if on_node.any():
        f, n = (int(i) for i in np.argwhere(on_node)[0])
        raise GeometryError(f"initial_state[{f}] position {x0[f, :2].tolist()} is at node {n}'s "
                            "position, where the measurement model is undefined")
    return _frozen(x0)


# ---------------------------------------------------------------------------
# The initial state


def initial_states(problem: FrameProblem, *, per_frame: bool = False) -> NDArray:
    """Where the solvers start, (F, 4) (docs/CONVENTIONS.md, "Initial values"):
    ``problem.initial_state`` when given, else the initial values, computed
    in numpy over the frames or, with ``per_frame`` (the solvers that solve
    one frame at a time), frame by frame in plain floats: the same numbers to
    rounding (the tests hold them equal to 1e-12), each solver always the
    same way, so that a frame starts from the same bits in a batch and alone.

    Position: the average of the observed nodes' own detections mapped to the
    global frame (the corrected eq. 19). Velocity: the least-squares solution
    of ``V_i = u_i^T v`` (``u_i`` the line of sight from node i to that
    position), each node's Doppler equation weighted by its own sigma and the
    prior's velocity part as regularizer; without a prior and with parallel
    lines of sight (or one node) the minimum-norm solution (the observable
    radial part only). A frame without observations starts at the prior mean
    (NaN without a prior); a frame whose position falls within 1 nm of an
    observed node gets a NaN velocity (its line of sight is undefined): the
    solvers flag both, they never raise.
    """
    if problem.initial_state is not None:
        return np.array(problem.initial_state)
    if per_frame and problem.poses.ndim == 2:
        return np.array(initial_state_floats(problem, problem.measurements.tolist(),
                                             problem.observed.tolist()),
                        dtype=float).reshape(problem.n_frames, 4)
    out = np.empty((problem.n_frames, 4))
    chunk = 8192
    for s in range(0, problem.n_frames, chunk):
        sl = slice(s, s + chunk)
        out[sl] = _start_arrays(problem.poses[sl] if problem.poses.ndim == 3 else problem.poses,
                                problem.measurements[sl], problem.observed[sl], problem)
    return out


def initial_state_floats(problem: FrameProblem, z_lists: list, observed_lists: list) -> list:
    """The initial values of :func:`initial_states` (``per_frame``) as F lists
    of 4 floats, of the frames ``z_lists`` (``problem.measurements.tolist()``)
    and ``observed_lists`` (``problem.observed.tolist()``) of a problem of
    one network without an ``initial_state``: for a solver that already holds
    the frames as lists (the scalar solver), the same floats."""
    start = problem.cached("start_floats", lambda: _StartFloats(problem))
    return [start(zl, ol) for zl, ol in zip(z_lists, observed_lists)]


def _doppler_weights(noise) -> tuple[float, list[float] | None]:
    """``(reference Doppler sigma, per-node weights or None)``: each Doppler
    equation weighted by ``(ref / sigma_i)^2`` (the first node's sigma the
    reference, so equal sigmas give weights exactly 1)."""
    sd = [m.doppler_mps for m in noise]
    if sd.count(sd[0]) == len(sd):
        return sd[0], None
    return sd[0], [(sd[0] / s) ** 2 for s in sd]


def _start_arrays(poses, z, obs, problem: FrameProblem) -> NDArray:
    """The initial values of frames ``z`` (F, N, 3), vectorized."""
    prior = problem.prior
    w = obs.astype(float)
    n_obs = w.sum(axis=1)
    det = detection_to_global(z[..., 0], z[..., 1], poses)  # (F, N, 2)
    with np.errstate(invalid="ignore", divide="ignore"):
        pos = np.sum(det * w[..., None], axis=1) / n_obs[:, None]
    d = pos[:, None, :] - poses[..., :2]
    dist = np.linalg.norm(d, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        u = np.where(dist < AT_NODE_M, np.nan, d / dist)
    u = np.where(w[..., None] > 0, u, 0.0)
    doppler_sigma, dw = _doppler_weights(problem.noise)
    wd = w if dw is None else w * np.asarray(dw)
    a = np.einsum("fn,fni,fnj->fij", wd, u, u)
    b = np.einsum("fn,fni,fn->fi", wd, u, z[..., 2])
    if prior is not None:
        reg = (doppler_sigma / prior.sigmas[2:]) ** 2
        a = a + np.diag(reg)
        b = b + reg * prior.mean[2:]
    state = np.concatenate([pos, _min_norm_2x2_arrays(a, b)], axis=1)
    state[n_obs == 0] = np.nan if prior is None else prior.mean
    return state


class _StartFloats:
    """The initial values of one frame in plain floats (the per-frame hot
    path; the tests check it against :func:`_start_arrays`), with the
    network's floats (poses, their cosines and sines, the Doppler weights,
    the prior's terms) taken once per network: ``start(z, observed)`` of a
    frame's ``z`` (N lists of 3 floats) and ``observed`` (N bools)."""

    __slots__ = ("poses", "trig", "sd", "dw", "prior")

    def __init__(self, problem: FrameProblem) -> None:
        self.poses = problem.poses.tolist()
        self.trig = [(math.cos(phi), math.sin(phi)) for _, _, phi in self.poses]
        self.sd, self.dw = _doppler_weights(problem.noise)
        prior = problem.prior
        if prior is None:
            self.prior = None
        else:
            m, ps = prior.mean.tolist(), prior.sigmas.tolist()
            self.prior = (m, (self.sd / ps[2]) ** 2, (self.sd / ps[3]) ** 2)

    def __call__(self, zl: list, ol: list) -> list[float]:
        pl, trig, prior = self.poses, self.trig, self.prior
        nodes = [i for i in range(len(pl)) if ol[i]]
        if not nodes:
            return list(prior[0]) if prior is not None else [math.nan] * 4
        sx = sy = 0.0
        for i in nodes:
            px, py, _ = pl[i]
            u, v = detection_to_local_scalar(zl[i][0], zl[i][1])
            c, s = trig[i]
            sx += px + u * c - v * s
            sy += py + u * s + v * c
        x, y = sx / len(nodes), sy / len(nodes)
        a11 = a12 = a22 = b1 = b2 = 0.0
        dw = self.dw
        for i in nodes:
            dx, dy = x - pl[i][0], y - pl[i][1]
            r = math.sqrt(dx * dx + dy * dy)
            if r < AT_NODE_M:
                return [x, y, math.nan, math.nan]
            ux, uy, zd = dx / r, dy / r, zl[i][2]
            if dw is not None:
                q = math.sqrt(dw[i])
                ux, uy, zd = ux * q, uy * q, zd * q
            a11 += ux * ux
            a12 += ux * uy
            a22 += uy * uy
            b1 += ux * zd
            b2 += uy * zd
        if prior is not None:
            m, r1, r2 = prior
            a11 += r1
            a22 += r2
            b1 += r1 * m[2]
            b2 += r2 * m[3]
        return [x, y, *_min_norm_2x2(a11, a12, a22, b1, b2)]


def _min_norm_2x2_arrays(a: NDArray, b: NDArray) -> NDArray:
    """Minimum-norm solutions of symmetric PSD 2x2 systems, (F, 2, 2) and (F, 2)
    (closed-form eigenvalues: ``np.linalg.eigh`` on 2x2 blocks costs ~0.85
    us/frame); the formula of :func:`_min_norm_2x2`."""
    a11, a12, a22 = a[:, 0, 0], a[:, 0, 1], a[:, 1, 1]
    b1, b2 = b[:, 0], b[:, 1]
    half_tr = 0.5 * (a11 + a22)
    disc = np.sqrt(0.25 * (a11 - a22) ** 2 + a12 * a12)
    hi, lo = half_tr + disc, half_tr - disc
    tol = 1e-10 * np.maximum(hi, 1e-300)
    det = a11 * a22 - a12 * a12
    out = np.zeros_like(b)
    with np.errstate(divide="ignore", invalid="ignore"):
        full = lo > tol
        out[:, 0] = np.where(full, (a22 * b1 - a12 * b2) / det, 0.0)
        out[:, 1] = np.where(full, (a11 * b2 - a12 * b1) / det, 0.0)
        rank1 = ~full & (hi > tol)  # project onto the eigenvector of the large eigenvalue
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


def _min_norm_2x2(a11, a12, a22, b1, b2) -> tuple[float, float]:
    """The minimum-norm solution of a symmetric PSD 2x2 system, in floats
    (as :func:`_min_norm_2x2_arrays`)."""
    half_tr = 0.5 * (a11 + a22)
    disc = math.sqrt(0.25 * (a11 - a22) ** 2 + a12 * a12)
    hi, lo = half_tr + disc, half_tr - disc
    tol = 1e-10 * max(hi, 1e-300)
    if lo > tol:
        det = a11 * a22 - a12 * a12
        return (a22 * b1 - a12 * b2) / det, (a11 * b2 - a12 * b1) / det
    if hi <= tol:
        return 0.0, 0.0
    e1, e2 = (a12, hi - a11) if abs(hi - a11) >= abs(hi - a22) else (hi - a22, a12)
    norm = math.hypot(e1, e2)
    if norm == 0.0:  # diagonal matrix: the eigenvector is an axis
        e1, e2 = (1.0, 0.0) if a11 >= a22 else (0.0, 1.0)
    else:
        e1, e2 = e1 / norm, e2 / norm
    k = (e1 * b1 + e2 * b2) / hi
    return k * e1, k * e2


def whitened_residuals(problem: FrameProblem, state: ArrayLike) -> NDArray:
    """(F, N, 3) ``(h(state) - z) / sigma`` of every frame at ``state`` (F, 4)
    (spatial frequency wrapped), NaN rows for the unobserved nodes."""
    x = np.asarray(state, dtype=float)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        h = predict_measurements(x[:, None, :], problem.poses)
    e = h - problem.measurements
    e[..., 1] = wrap_angle(e[..., 1])
    e = e / problem.sigmas
    e[~problem.observed] = np.nan
    return e
