"""The numpy pre-solve of the joint calibration graph: Levenberg-damped
Gauss-Newton (IRLS under a kernel, Nielsen's damping update). Each linear
solve eliminates the target states onto the poses: the state block is
block-tridiagonal (the constant-velocity factors link consecutive frames
only), so its banded Cholesky (7 sub-diagonals) is linear in frames, and the
few pose unknowns come from their dense Schur complement (the clock
offsets, when estimated, are one more unknown per node there; a general
sparse solve grows faster than linearly: docs/validation/calibration.md,
"Speed").

It uses the same models as the GTSAM factors (``measurement_model_pose``,
the body-frame pose tangent and ``Pose2.retract``, the state prior, the
constant-velocity information), so it converges to the same optimum; GTSAM
then needs one Gauss-Newton step, which is what keeps long recordings
affordable (a GTSAM ``CustomFactor`` costs a Python call per factor per
evaluation).

:func:`presolve` and :func:`normal_equations` take the graph as a
:class:`PresolveProblem` and the point as ``poses`` name -> (3,), ``states``
(F, 4) and, when clock offsets are estimated, ``offsets`` name -> seconds.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np
from numpy.typing import NDArray
import scipy.sparse as sp
import scipy.linalg as la

from factors.models import measurement_model, measurement_model_pose, residual
from factors.motion import cv_process_noise_continuous

from ...errors import ValidationError
from ...fusion.solvers.settings import LM_SETTINGS
from ..poses import pose_array, to_pose2

#: The key of the range offset (metres) in the pre-solve's ``offsets``
#: (not a node name: node names are strings).
RANGE_OFFSET = ("range offset",)

__all__ = ["PresolveProblem", "RANGE_OFFSET", "presolve", "normal_equations", "pose_influences",
           "cv_information", "kernel_weight", "robust_cost",
           "shifted_states", "motion_norms"]


def kernel_weight(norm: NDArray, robust: str | None, k: float) -> NDArray:
    """IRLS weight of GTSAM's mEstimators on a whitened residual norm."""
    if robust is None:
        return np.ones_like(norm)
    if robust == "huber":
        return np.where(norm <= k, 1.0, k / np.maximum(norm, 1e-300))
    return 1.0 / (1.0 + (norm / k) ** 2)  # cauchy


def robust_cost(norm: NDArray, robust: str | None, k: float) -> float:
    """GTSAM's cost of whitened residual norms under the kernel (0.5 e^2
    without), in forms that neither overflow for a huge ``k`` (the Gaussian
    limit) nor raise (numpy floats: inf, never OverflowError)."""
    norm = np.asarray(norm, dtype=float)
    half_sq = 0.5 * norm**2
    if robust is None:
        return float(np.sum(half_sq))
    k = np.float64(k)
    with np.errstate(over="ignore", invalid="ignore"):
        if robust == "huber":
            return float(np.sum(np.where(norm <= k, half_sq, k * (norm - 0.5 * k))))
        u2 = (norm / k) ** 2  # cauchy: 0.5 k^2 log(1 + u^2) = 0.5 e^2 log1p(u^2) / u^2
        ratio = np.where(u2 > 0, np.log1p(u2) / np.where(u2 > 0, u2, 1.0), 1.0)
        return float(np.sum(np.where(np.isinf(u2), 0.5 * k**2 * np.log1p(u2),
                                     half_sq * ratio)))


def cv_information(dt_s: float, sigma_a_mps2: float) -> NDArray:
    """(4, 4) information matrix of ``factors.constant_velocity_factor`` (its
    continuous white-noise acceleration covariance, inverted)."""
    return np.linalg.inv(cv_process_noise_continuous(dt_s, sigma_a_mps2))


@dataclass(frozen=True, slots=True)
class _Blocks:
    """The Gauss-Newton system by blocks: ``hss`` (F, 4, 4) the state
    diagonal blocks, ``off`` (G, 4, 4) the blocks ``H[mi, mi + 1]`` of the
    motion factors, ``bmat`` (F, 4, 3m) the state-pose coupling, ``hpp``
    (3m, 3m) the pose block, ``g`` the gradient (states, then poses)."""

    hss: NDArray
    off: NDArray
    mi: NDArray
    bmat: NDArray
    hpp: NDArray
    g: NDArray


def _state_band(hss: NDArray, off: NDArray, mi: NDArray, damping: NDArray) -> NDArray:
    """The state block (block-tridiagonal: the CV factors link consecutive
    frames only) in LAPACK's lower band storage, 7 sub-diagonals, with
    ``damping`` (4F,) added to the diagonal."""
    f = hss.shape[0]
    ab = np.zeros((8, 4 * f))
    cols = 4 * np.arange(f)
    for r in range(4):
        for c in range(r + 1):
            ab[r - c, cols + c] = hss[:, r, c]
    ab[0] += damping
    for i in range(4):  # H[4(k+1) + j, 4k + i] = off[k, i, j]
        for j in range(4):
            ab[4 + j - i, 4 * mi + i] = off[:, i, j]
    return ab


def _solve_blocks(b: _Blocks, lam: float) -> NDArray:
    """``-(H + lam diag(H))^-1 g`` by eliminating the states onto the poses:
    a banded Cholesky of the state block (linear in frames), then the dense
    Schur complement of the few pose unknowns. Raises LinAlgError when the
    damped system is not positive definite."""
    f = b.hss.shape[0]
    s0 = 4 * f
    d_s = np.maximum(np.einsum("kii->ki", b.hss).ravel(), 1e-12)
    chol = la.cholesky_banded(_state_band(b.hss, b.off, b.mi, lam * d_s), lower=True,
                              check_finite=True)
    bm = b.bmat.reshape(s0, -1)
    sol = la.cho_solve_banded((chol, True), np.column_stack([b.g[:s0], bm]),
                              check_finite=False)
    x_g, x_b = sol[:, 0], sol[:, 1:]
    if bm.shape[1] == 0:
        return -x_g
    c = b.hpp + lam * np.diag(np.maximum(np.diag(b.hpp), 1e-12))
    schur = c - bm.T @ x_b
    dp = la.solve(0.5 * (schur + schur.T), b.g[s0:] - bm.T @ x_g, assume_a="pos")
    return -np.concatenate([x_g - x_b @ dp, dp])


def _matvec(b: _Blocks, x: NDArray) -> NDArray:
    """``H x`` from the blocks."""
    f = b.hss.shape[0]
    s0 = 4 * f
    xs = x[:s0].reshape(f, 4)
    bm = b.bmat.reshape(s0, -1)
    ys = (b.hss @ xs[:, :, None])[:, :, 0]
    ys[b.mi] += (b.off @ xs[b.mi + 1][:, :, None])[:, :, 0]
    ys[b.mi + 1] += (np.swapaxes(b.off, 1, 2) @ xs[b.mi][:, :, None])[:, :, 0]
    return np.concatenate([ys.ravel() + bm @ x[s0:], bm.T @ x[:s0] + b.hpp @ x[s0:]])


class _Problem:
    """The calibration graph's cost, normal equations and update, in numpy.

    Unknowns: the states first, the poses of the nodes but the reference
    last (the pose rows are dense; eliminating them last keeps the
    factorization's fill-in to the pose block).
    """

    def __init__(self, measurements, names, reference, sigmas, prior_sigmas, robust, k, use,
                 motion, n_frames, timed=(), range_offset=None):
        self.meas = measurements
        self.names = list(names)
        self.ref = reference
        self.others = [n for n in self.names if n != reference]
        self.sigmas = sigmas
        self.robust, self.k = robust, k
        self.f = n_frames
        self.s0 = 4 * n_frames
        # The clock offsets (seconds) of the nodes in ``timed`` follow the poses.
        self.timed = [n for n in self.others if n in set(timed)]
        p0 = 3 * len(self.others)
        # Columns of each node's unknowns within the pose block: its pose,
        # then its offset (after every pose) when timed.
        self.cols = {n: np.array(list(range(3 * i, 3 * i + 3))
                                 + ([p0 + self.timed.index(n)] if n in self.timed else []))
                     for i, n in enumerate(self.others)}
        self.dim = self.s0 + p0 + len(self.timed)
        # The range offset (module doc), when estimated: one more unknown
        # after the clock offsets, with its prior (mean, sigma) in metres.
        self.range_prior = None if range_offset is None else tuple(map(float, range_offset))
        self.dcol = None
        if self.range_prior is not None:
            self.dcol = self.dim - self.s0
            self.dim += 1
        self.use = ({n: np.isfinite(measurements[n][:, 0]) for n in self.names} if use is None
                    else use)
        self.prior_w = 1.0 / np.asarray(prior_sigmas, dtype=float) ** 2
        self.sidx = 4 * np.arange(n_frames)[:, None] + np.arange(4)[None, :]  # (f, 4) columns
        self.mi = None
        if motion is not None and len(motion[0]):
            self.mi = np.asarray(motion[0], dtype=int)
            dts, which = np.unique(np.asarray(motion[1], dtype=float), return_inverse=True)
            self.lam_cv = np.array([cv_information(dt, motion[2]) for dt in dts])[which.ravel()]
            self.fm = np.tile(np.eye(4), (self.mi.size, 1, 1))
            self.fm[:, 0, 2] = self.fm[:, 1, 3] = np.asarray(motion[1], dtype=float)
            # Optional kernel on the motion factors' whitened norm (sharp turns).
            self.motion_robust, self.motion_k = (motion[3], motion[4]) if len(motion) > 3 else (None, 1.0)

    def range_offset(self, offsets) -> float:
        """The range offset (m) in ``offsets`` (0 when not estimated)."""
        if self.dcol is None or offsets is None:
            return 0.0
        return float(offsets.get(RANGE_OFFSET, 0.0))

    def cost(self, poses, states, offsets=None) -> float:
        c = 0.5 * np.sum(self.prior_w * states**2)
        d = self.range_offset(offsets)
        if self.dcol is not None:
            c += 0.5 * ((d - self.range_prior[0]) / self.range_prior[1]) ** 2
        for n in self.names:
            ok = self.use[n]
            h, _ = measurement_model(shifted_states(states[ok], _offset(offsets, n)), poses[n])
            h[:, 0] -= d
            c += robust_cost(np.linalg.norm(residual(h, self.meas[n][ok]) / self.sigmas, axis=1),
                             self.robust, self.k)
        if self.mi is not None:
            c += robust_cost(self.motion_norms(states), self.motion_robust, self.motion_k)
        return c

    def _node_residuals(self, n, poses, states, offsets, d):
        """Node ``n``'s rows in use, clock offset, whitened residuals (K, 3)
        and the model's pose and state Jacobians at ``(poses, states,
        offsets)`` with every range shortened by the range offset ``d``."""
        ok = self.use[n]
        tau = _offset(offsets, n)
        h, jp, js = measurement_model_pose(poses[n], shifted_states(states[ok], tau))
        h[:, 0] -= d
        return ok, tau, residual(h, self.meas[n][ok]) / self.sigmas, jp, js

    def _measurement_blocks(self, poses, states, offsets, hss, gs, g, bmat):
        """Add the measurement factors' blocks: the states' (``hss``, ``gs``),
        the pose-state coupling ``bmat`` (F, 4, P); returns the pose block
        (P, P) (poses, then clock offsets)."""
        p = self.dim - self.s0
        hpp = np.zeros((p, p))
        sig = self.sigmas
        d = self.range_offset(offsets)
        for n in self.names:
            ok, tau, e, jp, js = self._node_residuals(n, poses, states, offsets, d)
            w = kernel_weight(np.linalg.norm(e, axis=1), self.robust, self.k)
            js = js / sig[:, None]
            if n in self.timed:  # d h / d tau = J[:, :2] v; d h / d x = J F(tau)
                jt = js[:, :, :2] @ states[ok, 2:, None]
                js = js.copy()
                js[:, :, 2:] += tau * js[:, :, :2]
                jp = np.concatenate([jp, jt * sig[:, None]], axis=2)
            ew = e * w[:, None]
            jsw = np.swapaxes(js, 1, 2) * w[:, None, None]  # (K, 4, 3), matmul: no einsum loops
            hss[ok] += jsw @ js
            gs[ok] += (np.swapaxes(js, 1, 2) @ ew[:, :, None])[:, :, 0]
            if self.dcol is not None:
                self._range_offset_blocks(n, ok, jp, jsw, ew, w, hpp, g, bmat)
            if n != self.ref:
                cols = self.cols[n]
                jp = jp / sig[:, None]
                jpf = jp.reshape(-1, cols.size)
                hpp[np.ix_(cols, cols)] += jpf.T @ (jpf * np.repeat(w, 3)[:, None])
                g[self.s0 + cols] += jpf.T @ ew.ravel()
                rows = np.flatnonzero(ok)
                bmat[rows[:, None, None], np.arange(4)[None, :, None],
                     cols[None, None, :]] += jsw @ jp  # (K, 4, q)
        return hpp

    def _range_offset_blocks(self, n, ok, jp, jsw, ew, w, hpp, g, bmat):
        """Add node ``n``'s terms of the range offset (every node's range
        is ``|p - p_i| - d``: whitened Jacobian ``-1 / sigma_range`` on the
        range row): its diagonal, gradient, coupling with the states and
        with the node's pose (and clock offset)."""
        dc, sr = self.dcol, self.sigmas[0]
        hpp[dc, dc] += np.sum(w) / sr**2
        g[self.s0 + dc] -= np.sum(ew[:, 0]) / sr
        rows = np.flatnonzero(ok)
        bmat[rows, :, dc] -= jsw[:, :, 0] / sr
        if n != self.ref:
            cols = self.cols[n]
            jpw = jp / self.sigmas[:, None]  # whitened (K, 3, q)
            cross = -np.sum(jpw[:, 0, :] * w[:, None], axis=0) / sr
            hpp[cols, dc] += cross
            hpp[dc, cols] += cross

    def motion_norms(self, states) -> NDArray:
        """(G,) whitened norms ``sqrt(e^T Lambda e)`` of the CV factors."""
        e = states[self.mi + 1] - (self.fm @ states[self.mi][:, :, None])[:, :, 0]
        return np.sqrt(np.maximum(np.sum(e * (self.lam_cv @ e[:, :, None])[:, :, 0], axis=1), 0))

    def _motion_blocks(self, states, hss, gs):
        """Add the CV factors' blocks (IRLS-weighted under the motion
        kernel); returns the (G, 4, 4) blocks H[k, k+1]."""
        mi, fm, lam_cv = self.mi, self.fm, self.lam_cv
        if self.motion_robust is not None:
            w = kernel_weight(self.motion_norms(states), self.motion_robust, self.motion_k)
            lam_cv = lam_cv * w[:, None, None]
        fmt = np.swapaxes(fm, 1, 2)
        e = states[mi + 1] - (fm @ states[mi][:, :, None])[:, :, 0]
        le = (lam_cv @ e[:, :, None])[:, :, 0]
        off = -(fmt @ lam_cv)  # d(k) x d(k+1) block
        hss[mi] -= off @ fm
        hss[mi + 1] += lam_cv
        gs[mi] -= (fmt @ le[:, :, None])[:, :, 0]
        gs[mi + 1] += le
        return off

    def blocks(self, poses, states, offsets=None) -> _Blocks:
        """The Gauss-Newton system at ``(poses, states, offsets)`` by blocks."""
        g = np.zeros(self.dim)
        hss = np.tile(np.diag(self.prior_w), (self.f, 1, 1))
        gs = states * self.prior_w
        bmat = np.zeros((self.f, 4, self.dim - self.s0))
        hpp = self._measurement_blocks(poses, states, offsets, hss, gs, g, bmat)
        if self.dcol is not None:  # the range offset's prior
            mean, sigma = self.range_prior
            hpp[self.dcol, self.dcol] += 1.0 / sigma**2
            g[self.s0 + self.dcol] += (self.range_offset(offsets) - mean) / sigma**2
        off = (self._motion_blocks(states, hss, gs) if self.mi is not None
               else np.zeros((0, 4, 4)))
        g[:self.s0] = gs.ravel()
        mi = self.mi if self.mi is not None else np.zeros(0, dtype=int)
        return _Blocks(hss=hss, off=off, mi=mi, bmat=bmat, hpp=hpp, g=g)

    def influences(self, poses, states, offsets=None) -> tuple[NDArray, NDArray]:
        """Each frame's influence on the pose block at a solution and the
        model's covariance of that block (:func:`pose_influences`)."""
        blk = self.blocks(poses, states, offsets)
        s0, p = self.s0, self.dim - self.s0
        chol = la.cholesky_banded(_state_band(blk.hss, blk.off, blk.mi, np.zeros(s0)),
                                  lower=True)
        bm = blk.bmat.reshape(s0, p)
        y = la.cho_solve_banded((chol, True), bm, check_finite=False)  # H_ss^-1 H_sp
        schur = blk.hpp - bm.T @ y
        cov = la.inv(0.5 * (schur + schur.T))
        yk = y.reshape(self.f, 4, p)
        psi = self._frame_pose_gradients(poses, states, offsets)
        gs = blk.g[:s0].reshape(self.f, 4).copy()
        if self.mi is not None:
            # The motion factor k -> k+1 belongs to frame k: its gradient at
            # state k + 1 leaves frame k + 1's share and joins frame k's.
            mi = self.mi
            e = states[mi + 1] - (self.fm @ states[mi][:, :, None])[:, :, 0]
            le = (self.lam_cv @ e[:, :, None])[:, :, 0]
            ga = -(np.swapaxes(self.fm, 1, 2) @ le[:, :, None])[:, :, 0]
            np.subtract.at(gs, mi, ga)
            np.subtract.at(gs, mi + 1, le)
            psi[mi] -= (np.einsum("kip,ki->kp", yk[mi], ga)
                        + np.einsum("kip,ki->kp", yk[mi + 1], le))
        psi -= np.einsum("kip,ki->kp", yk, gs)
        if self.dcol is not None:  # the prior's share of the gradient, spread evenly
            d = self.range_offset(offsets)
            psi[:, self.dcol] += (d - self.range_prior[0]) / self.range_prior[1] ** 2 / self.f
        return psi @ cov, cov

    def _frame_pose_gradients(self, poses, states, offsets) -> NDArray:
        """(F, P) each frame's measurement gradient with respect to the pose
        block (Gaussian: the final pass has no kernel)."""
        psi = np.zeros((self.f, self.dim - self.s0))
        sig = self.sigmas
        d = self.range_offset(offsets)
        for n in self.names:
            ok, _, e, jp, js = self._node_residuals(n, poses, states, offsets, d)
            rows = np.flatnonzero(ok)
            if self.dcol is not None:
                psi[rows, self.dcol] -= e[:, 0] / sig[0]
            if n == self.ref:
                continue
            if n in self.timed:
                jt = (js / sig[:, None])[:, :, :2] @ states[ok, 2:, None]
                jp = np.concatenate([jp, jt * sig[:, None]], axis=2)
            jp = jp / sig[:, None]
            psi[np.ix_(rows, self.cols[n])] += np.einsum("kri,kr->ki", jp, e)
        return psi

    def system(self, poses, states, offsets=None) -> tuple[sp.csc_matrix, NDArray]:
        """Gauss-Newton Hessian (sparse) and gradient at ``(poses, states, offsets)``."""
        b = self.blocks(poses, states, offsets)
        sidx = self.sidx
        rows = [np.broadcast_to(sidx[:, :, None], b.hss.shape).ravel()]
        cols = [np.broadcast_to(sidx[:, None, :], b.hss.shape).ravel()]
        vals = [b.hss.ravel()]
        for r, c, v in ((sidx[b.mi][:, :, None], sidx[b.mi + 1][:, None, :], b.off),
                        (sidx[b.mi + 1][:, :, None], sidx[b.mi][:, None, :],
                         np.swapaxes(b.off, 1, 2))):
            rows.append(np.broadcast_to(r, v.shape).ravel())
            cols.append(np.broadcast_to(c, v.shape).ravel())
            vals.append(v.ravel())
        hss = sp.csc_matrix((np.concatenate(vals), (np.concatenate(rows),
                                                     np.concatenate(cols))),
                            shape=(self.s0, self.s0))
        bm = sp.csc_matrix(b.bmat.reshape(self.s0, -1))
        hmat = sp.bmat([[hss, bm], [bm.T, sp.csc_matrix(b.hpp)]], format="csc")
        return hmat, b.g

    def apply(self, poses, states, offsets, delta):
        new = dict(poses)
        for i, n in enumerate(self.others):
            new[n] = pose_array(to_pose2(poses[n]).retract(delta[self.s0 + 3 * i:self.s0 + 3 * i + 3]))
        new_offsets = None if offsets is None else dict(offsets)
        for n in self.timed:
            new_offsets[n] = float(offsets[n] + delta[self.s0 + self.cols[n][3]])
        if self.dcol is not None:
            new_offsets[RANGE_OFFSET] = self.range_offset(offsets) + float(
                delta[self.s0 + self.dcol])
        return new, states + delta[:self.s0].reshape(self.f, 4), new_offsets


def motion_norms(states: NDArray, motion) -> NDArray:
    """(G,) whitened norms ``sqrt(e^T Lambda e)`` of the constant-velocity
    factors ``motion`` (module doc) at ``states`` (F, 4)."""
    mi = np.asarray(motion[0], dtype=int)
    if mi.size == 0:
        return np.zeros(0)
    dt = np.asarray(motion[1], dtype=float)
    e = states[mi + 1] - states[mi]
    e[:, :2] -= dt[:, None] * states[mi, 2:]
    dts, which = np.unique(dt, return_inverse=True)
    lam = np.array([cv_information(d, motion[2]) for d in dts])[which.ravel()]
    return np.sqrt(np.maximum(np.einsum("gi,gij,gj->g", e, lam, e), 0.0))


def _offset(offsets, name) -> float:
    return 0.0 if offsets is None else float(offsets.get(name, 0.0))


def shifted_states(states: NDArray, offset_s: float) -> NDArray:
    """``F(offset_s) x`` for states (..., 4): the constant-velocity state
    ``offset_s`` seconds later (positions moved by ``offset_s * v``)."""
    if offset_s == 0.0:
        return states
    out = np.array(states, dtype=float)
    out[..., :2] += offset_s * out[..., 2:]
    return out


@dataclass(frozen=True, kw_only=True, slots=True)
class PresolveProblem:
    """The calibration graph as the pre-solve sees it.

    measurements : name -> (F, 3) (NaN rows where the node saw nothing).
    names : the nodes; reference : the one whose pose is held at the origin.
    sigmas : (3,) measurement noise; prior_sigmas : (4,) of the zero-mean
        state prior.
    robust : None, ``"huber"`` or ``"cauchy"``, with kernel width ``k``.
    use : name -> (F,) bool, the detections in the graph (None: every finite
        one).
    motion : ``(index (G,), dt_s (G,), sigma_a_mps2)`` of the
        constant-velocity factors between states ``index`` and ``index + 1``,
        optionally followed by ``(robust, k)``: a kernel on the motion
        factors' whitened norms (sharp turns are not Gaussian accelerations);
        None: no motion factors.
    """

    measurements: Mapping[str, NDArray]
    names: Sequence[str]
    reference: str
    sigmas: NDArray
    prior_sigmas: NDArray
    robust: str | None = None
    k: float = 1.0
    use: Mapping[str, NDArray] | None = field(default=None)
    motion: tuple | None = None
    range_offset: tuple[float, float] | None = None


def _problem(problem: PresolveProblem, poses, states, offsets=None):
    poses = {n: np.asarray(p, dtype=float).copy() for n, p in poses.items()}
    states = np.array(states, dtype=float)
    q = problem
    given = {} if offsets is None else dict(offsets)
    timed = tuple(n for n in given if n != RANGE_OFFSET)
    prob = _Problem(q.measurements, q.names, q.reference, np.asarray(q.sigmas, dtype=float),
                    q.prior_sigmas, q.robust, q.k, q.use, q.motion, states.shape[0],
                    timed=timed, range_offset=q.range_offset)
    if offsets is not None and (timed or q.range_offset is None):
        offsets = {n: float(given.get(n, 0.0)) for n in q.names}
    elif q.range_offset is not None:
        offsets = {}
    if q.range_offset is not None:
        offsets[RANGE_OFFSET] = float(given.get(RANGE_OFFSET, q.range_offset[0]))
    return prob, poses, states, offsets


def pose_influences(problem: PresolveProblem, poses: Mapping[str, NDArray], states: NDArray,
                    *, offsets: Mapping | None = None) -> tuple[NDArray, NDArray]:
    """Each frame's influence on the pose block at a solution of the
    (Gaussian) graph, ``(F, P)``, and the model's covariance of that block
    ``S^-1`` (``S`` the Schur complement onto it), in the block's order: the
    non-reference poses (body tangent), the clock offsets of the nodes in
    ``offsets``, the range offset when ``problem.range_offset`` is set.

    Frame ``k``'s score with the states eliminated is ``psi_k = g_p[k] -
    Y_k^T g_s[k]`` (``Y = H_ss^-1 H_sp``; ``g_p[k]``, ``g_s[k]`` the
    gradients of frame ``k``'s measurement and prior factors and of its
    outgoing motion factor); its influence is ``S^-1 psi_k``: the influences
    sum to zero at the optimum, and their summed outer products equal ``S^-1``
    on the average when the model holds (:mod:`.covariance`)."""
    if problem.robust is not None:
        raise ValidationError("pose_influences needs the Gaussian graph (robust=None)")
    prob, poses, states, offsets = _problem(problem, poses, states, offsets)
    return prob.influences(poses, states, offsets)


def normal_equations(problem: PresolveProblem, poses: Mapping[str, NDArray], states: NDArray,
                     *, offsets: Mapping[str, float] | None = None
                     ) -> tuple[sp.csc_matrix, NDArray]:
    """The pre-solve's linear system at a point (module doc): the sparse
    Gauss-Newton Hessian (IRLS-weighted under a kernel) and the gradient,
    states first then the non-reference poses (body tangent), then the
    clock offsets of the non-reference nodes in ``offsets`` (when given).
    GTSAM's ``linearize(...).hessian`` of the same graph gives the same
    matrices."""
    prob, poses, states, offsets = _problem(problem, poses, states, offsets)
    return prob.system(poses, states, offsets)


def _damped_step(prob, poses, states, offsets, cost, lam, nu):
    """One accepted Levenberg step (up to 12 damping increases), or None."""
    blk = prob.blocks(poses, states, offsets)
    g = blk.g
    for _ in range(12):
        try:
            delta = _solve_blocks(blk, lam)
        except (la.LinAlgError, ValueError):
            delta = np.full(prob.dim, np.nan)
        if not np.all(np.isfinite(delta)):
            lam, nu = lam * nu, nu * 2.0
            continue
        new_poses, new_states, new_offsets = prob.apply(poses, states, offsets, delta)
        new_cost = prob.cost(new_poses, new_states, new_offsets)
        predicted = -(g @ delta + 0.5 * delta @ _matvec(blk, delta))
        rho = (cost - new_cost) / max(predicted, 1e-300)
        if new_cost <= cost and rho > 0:
            # Nielsen's damping update (as in Madsen, Nielsen & Tingleff)
            lam = max(LM_SETTINGS.lambda_min, lam * LM_SETTINGS.damping_update(rho))
            return (new_poses, new_states, new_offsets, new_cost), lam, 2.0
        lam, nu = lam * nu, nu * 2.0
    return None, lam, nu


def presolve(problem: PresolveProblem, poses: Mapping[str, NDArray], states: NDArray, *,
             offsets: Mapping[str, float] | None = None, max_steps: int = 50,
             tol: float = 1e-7, report: dict | None = None):
    """Levenberg-damped Gauss-Newton on the calibration graph (module doc),
    from ``(poses, states)``; stops after ``max_steps`` steps, when no damping
    gives a lower cost, or when a step lowers the cost by at most ``tol``
    relative (converged). Returns the updated ``(poses, states)``; with
    ``offsets`` (name -> clock offset in seconds, estimated for every
    non-reference node it names: node ``n`` measures ``F(offset) x_k``,
    :func:`shifted_states`) it returns ``(poses, states, offsets)``. A
    ``report`` dict receives ``initial_cost``, ``cost`` (GTSAM's error of the
    same graph), ``steps`` and ``converged``."""
    timed = offsets is not None or problem.range_offset is not None
    prob, poses, states, offsets = _problem(problem, poses, states, offsets)
    lam, nu = LM_SETTINGS.lambda_initial, LM_SETTINGS.lambda_factor
    cost = initial_cost = prob.cost(poses, states, offsets)
    steps, done = 0, False
    while steps < max_steps and not done:
        step, lam, nu = _damped_step(prob, poses, states, offsets, cost, lam, nu)
        if step is None:
            done = True  # no damping lowers the cost: at the optimum to rounding
            break
        new_poses, new_states, new_offsets, new_cost = step
        done = (cost - new_cost) <= tol * max(cost, 1.0)
        poses, states, offsets, cost = new_poses, new_states, new_offsets, new_cost
        steps += 1
    if report is not None:
        report.update(initial_cost=float(initial_cost), cost=float(cost), steps=steps,
                      converged=bool(done))
    return (poses, states, offsets) if timed else (poses, states)
