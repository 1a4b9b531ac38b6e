"""Joint calibration graph: node poses and the target's states from the raw
measurements (docs/CONVENTIONS.md, "Pairwise self-calibration", last paragraph).

Variables: every node's ``Pose2`` but the reference's (S1, fixed at the
origin), and the target's state ``(x, y, vx, vy)`` at every frame that at
least two nodes detected. Factors:

- per node and frame, range + spatial frequency + Doppler: the reference
  node through ``factors.node_measurement_factor`` (known pose), the others
  through ``factors.pose_measurement_factor`` (form b), each whitened by
  ``factors.measurement_noise(sigmas)``, optionally under a Huber or Cauchy
  kernel against ghost detections;
- a weak prior per state (paper eq. 16 velocity prior, 3.5 m/s; a 1 km
  position prior that only keeps the system well posed);
- optionally, ``factors.constant_velocity_factor`` between consecutive frames.

The closed form (on each node's detections mapped to local xy, with a trimmed
refit that drops frames whose alignment residual is far above the median)
gives the initial poses, a pose graph over all node pairs when N > 2; LM
solves. With a robust kernel, detections whose whitened residual exceeds the
chi-square(3) ``outlier_probability`` quantile are flagged as outliers and a
final Gaussian LM pass on the inliers gives the estimate and
``gtsam.Marginals`` the covariances (a robust kernel's weights would inflate
them). When the marginals are singular or a pose variance exceeds
``max_pose_variance``, the result has ``success=False`` and names the
unobservable direction (e.g. a standing target: a node may turn about it).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal, Mapping

import gtsam
import numpy as np
from numpy.typing import ArrayLike, NDArray
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.stats import chi2

from factors.gtsam_factors import (
    constant_velocity_factor,
    measurement_noise,
    node_measurement_factor,
    pose_measurement_factor,
    state_prior_factor,
)
from factors.models import (
    detection_to_local,
    local_to_global,
    measurement_model,
    measurement_model_pose,
    residual,
)

from ..errors import CalibrationError, ValidationError
from ..data.recording import Detections
from .._validation import as_float_array, check_finite, check_positive, check_shape
from .closed_form import (
    DEFAULT_MIN_COMMON_FRAMES,
    DEFAULT_MIN_SPREAD_M,
    closed_form_calibration,
    closed_form_pose,
)
from .pose_graph import PoseEdge, pose_graph_calibration
from .poses import pose_array, to_pose2

__all__ = ["PAPER_SIGMAS", "JointCalibration", "joint_calibration", "trimmed_closed_form"]

#: Paper measurement noise (its resolutions; docs/CONVENTIONS.md): range_m,
#: omega_rad, doppler_mps.
PAPER_SIGMAS = (0.035, np.pi / 4, 0.1807)


@dataclass(frozen=True, kw_only=True, slots=True)
class JointCalibration:
    """Result of :func:`joint_calibration`.

    poses, covariances : name -> (3,) pose and (3, 3) marginal covariance
        (body tangent) of every calibrated node; the reference's is zero.
    initial_poses : the closed-form starting poses.
    frames : (F,) int, the frames in the graph. states : (F, 4) the target
        states, global. state_covariances : (F, 4, 4) their marginals (NaN
        when the marginals failed).
    outliers : name -> (F,) bool, detections flagged as outliers (False where
        the node has no detection).
    unobservable : name -> (m, 3) unit directions (body tangent) along which
        the node's pose is not determined; empty when all is observable.
    unreachable : nodes left out (no common frames with the others).
    """

    reference: str
    poses: Mapping[str, NDArray]
    covariances: Mapping[str, NDArray]
    initial_poses: Mapping[str, NDArray]
    frames: NDArray
    states: NDArray
    state_covariances: NDArray
    outliers: Mapping[str, NDArray]
    success: bool
    message: str
    iterations: int = 0
    initial_error: float = float("nan")
    final_error: float = float("nan")
    unobservable: Mapping[str, NDArray] = field(default_factory=dict)
    unreachable: tuple[str, ...] = ()


def _residuals(pose, points_a_m, points_b_m):
    c, s = np.cos(pose[2]), np.sin(pose[2])
    bx, by = points_b_m[:, 0], points_b_m[:, 1]
    return np.hypot(points_a_m[:, 0] - (pose[0] + c * bx - s * by),
                    points_a_m[:, 1] - (pose[1] + s * bx + c * by))


def trimmed_closed_form(points_a_m: NDArray, points_b_m: NDArray, *, n_rounds: int = 3,
                        trim_factor: float = 2.5, n_subsets: int = 200, subset_size: int = 6,
                        seed: int = 0, **kwargs):
    """A robust closed form for starting poses: least median of squares over
    ``n_subsets`` random ``subset_size``-frame subsets (the bare closed form
    on each; robust to up to half the frames being ghosts), then the closed
    form refitted ``n_rounds`` times on the frames whose alignment residual
    is below ``trim_factor`` times the median residual. Deterministic
    (``seed``). Returns ``(PairwiseCalibration, inlier mask (K,))``."""
    k = points_a_m.shape[0]
    full = closed_form_calibration(points_a_m, points_b_m, **kwargs)  # validates
    best_pose, best_med = full.pose, np.median(_residuals(full.pose, points_a_m, points_b_m))
    rng = np.random.default_rng(seed)
    m = min(subset_size, k)
    for _ in range(n_subsets):
        idx = rng.choice(k, size=m, replace=False)
        pose, _ = closed_form_pose(points_a_m[idx], points_b_m[idx])
        med = np.median(_residuals(pose, points_a_m, points_b_m))
        if med < best_med:
            best_pose, best_med = pose, med
    keep = np.ones(k, dtype=bool)
    cal, pose = full, best_pose
    for _ in range(n_rounds):
        r = _residuals(pose, points_a_m, points_b_m)
        new_keep = r <= trim_factor * np.median(r)
        if new_keep.sum() < max(3, int(kwargs.get("min_common_frames", 3))):
            break
        if np.array_equal(new_keep, keep) and cal is not full:
            break
        keep = new_keep
        cal = closed_form_calibration(points_a_m[keep], points_b_m[keep], **kwargs)
        pose = cal.pose
    return cal, keep


def _detections_table(dets: Mapping[str, Detections]):
    out = {}
    for name, d in dets.items():
        if isinstance(d, Detections):
            fr, z = d.frame, d.measurements
        else:
            try:
                fr, z = d
            except (TypeError, ValueError):
                raise ValidationError(f"detections[{name!r}] must be Detections or a "
                                      f"(frame, measurements) pair") from None
            fr = np.asarray(fr)
            z = check_finite(check_shape(as_float_array(z, f"detections[{name!r}] measurements"),
                                         (fr.shape[0], 3), f"detections[{name!r}] measurements"),
                             f"detections[{name!r}] measurements")
        fr = np.asarray(fr, dtype=np.int64)
        if np.unique(fr).size != fr.size:
            raise CalibrationError(f"node {name}: several detections in one frame; the joint "
                                   f"calibration needs one target detection per node per frame")
        order = np.argsort(fr)
        out[str(name)] = (fr[order], np.asarray(z, dtype=float)[order])
    return out


def _initial_states(meas_f, poses, names, sigmas, prior_v_sigma, gn_steps=3):
    """Average of each node's detection mapped to global (docs/CONVENTIONS.md, initial
    values) and the velocity from the Dopplers by regularized least squares."""
    sigma_range, sigma_omega, sigma_doppler = sigmas
    f = next(iter(meas_f.values())).shape[0]
    pos_sum = np.zeros((f, 2))
    count = np.zeros(f)
    for n in names:
        z = meas_f[n]
        ok = np.isfinite(z[:, 0])
        g = local_to_global(detection_to_local(z[ok, 0], z[ok, 1]), poses[n])
        pos_sum[ok] += g
        count[ok] += 1
    pos = pos_sum / count[:, None]
    # A few Gauss-Newton steps per frame on range + spatial frequency with
    # the poses held: each frame's position at its own optimum, so LM starts
    # near the joint solution (vectorized over frames; 2x2 solves).
    w = np.array([1.0 / sigma_range**2, 1.0 / sigma_omega**2])
    for _ in range(gn_steps):
        a = np.tile(np.eye(2) * 1e-9, (f, 1, 1))
        b = np.zeros((f, 2))
        state = np.concatenate([pos, np.zeros((f, 2))], axis=1)
        for n in names:
            z = meas_f[n]
            ok = np.isfinite(z[:, 0])
            h, jac = measurement_model(state[ok], poses[n])
            e = residual(h, z[ok])[:, :2]
            j = jac[:, :2, :2]
            a[ok] += np.einsum("kri,r,krj->kij", j, w, j)
            b[ok] -= np.einsum("kri,r,kr->ki", j, w, e)
        step = np.linalg.solve(a, b[..., None])[..., 0]
        # cap a step at 1 m: a ghost can make one frame's problem ill posed
        norm = np.linalg.norm(step, axis=1, keepdims=True)
        pos = pos + step * np.minimum(1.0, 1.0 / np.maximum(norm, 1e-12))
    a = np.tile(np.eye(2) / prior_v_sigma**2, (f, 1, 1))
    b = np.zeros((f, 2))
    for n in names:
        z = meas_f[n]
        ok = np.isfinite(z[:, 0])
        d = pos[ok] - poses[n][:2]
        u = d / np.linalg.norm(d, axis=1, keepdims=True)
        a[ok] += np.einsum("ki,kj->kij", u, u) / sigma_doppler**2
        b[ok] += u * z[ok, 2:3] / sigma_doppler**2
    vel = np.linalg.solve(a, b[..., None])[..., 0]
    return np.concatenate([pos, vel], axis=1)


def _kernel_weight(norm, robust, k):
    """IRLS weight of GTSAM's mEstimators on a whitened residual norm."""
    if robust is None:
        return np.ones_like(norm)
    if robust == "huber":
        return np.where(norm <= k, 1.0, k / np.maximum(norm, 1e-300))
    return 1.0 / (1.0 + (norm / k) ** 2)  # cauchy


def _cv_information(dt_s, sigma_a_mps2):
    """Information matrix of ``factors.constant_velocity_factor`` (its
    continuous white-noise acceleration covariance, inverted)."""
    t = float(dt_s)
    q1 = sigma_a_mps2**2 * t * np.array([[t**3 / 3, t**2 / 2], [t**2 / 2, t]])
    cov = np.zeros((4, 4))
    cov[np.ix_([0, 2], [0, 2])] = q1
    cov[np.ix_([1, 3], [1, 3])] = q1
    return np.linalg.inv(cov)


def _robust_cost(norm, robust, k):
    if robust is None:
        return 0.5 * np.sum(norm**2)
    if robust == "huber":
        return np.sum(np.where(norm <= k, 0.5 * norm**2, k * norm - 0.5 * k**2))
    return np.sum(0.5 * k**2 * np.log1p((norm / k) ** 2))


def _presolve(meas_f, poses, states, names, ref, sigmas, prior_sig, robust, k, *,
              use=None, motion=None, max_steps=50, tol=1e-7, _system_only=False):
    """Levenberg-damped Gauss-Newton (IRLS under a kernel) on the same
    calibration graph, in numpy with a sparse direct solve.

    It uses the same models as the GTSAM factors (``measurement_model_pose``,
    the body-frame pose tangent and ``Pose2.retract``, the state prior, the
    constant-velocity information), so it converges to the same optimum; the
    GTSAM LM that follows then needs an iteration or two, which is what makes
    600 frames fit in well under a second (a GTSAM ``CustomFactor`` costs a
    Python call per factor per evaluation). ``motion`` is ``(index (G,),
    dt_s (G,), sigma_a_mps2)`` of the motion factors between states
    ``index`` and ``index + 1``. Returns updated ``(poses, states)``.
    """
    others = [n for n in names if n != ref]
    m = len(others)
    f = states.shape[0]
    # States first, poses last: the pose rows are dense, and eliminating
    # them last keeps the factorization's fill-in to the pose block.
    s0 = 4 * f
    p0 = s0
    dim = s0 + 3 * m
    poses = {n: np.asarray(p, dtype=float).copy() for n, p in poses.items()}
    states = states.copy()
    use = {n: np.isfinite(meas_f[n][:, 0]) for n in names} if use is None else use
    prior_w = 1.0 / np.asarray(prior_sig, dtype=float) ** 2
    if motion is not None and len(motion[0]):
        mi = np.asarray(motion[0], dtype=int)
        lam_cv = np.array([_cv_information(dt, motion[2]) for dt in motion[1]])
        fm = np.tile(np.eye(4), (mi.size, 1, 1))
        fm[:, 0, 2] = fm[:, 1, 3] = np.asarray(motion[1], dtype=float)
    else:
        mi = None
    sidx = 4 * np.arange(f)[:, None] + np.arange(4)[None, :]  # (f, 4) state columns

    def cost_of(poses, states):
        c = 0.5 * np.sum(prior_w * states**2)
        for n in names:
            ok = use[n]
            h, _ = measurement_model(states[ok], poses[n])
            c += _robust_cost(np.linalg.norm(residual(h, meas_f[n][ok]) / sigmas, axis=1),
                              robust, k)
        if mi is not None:
            e = states[mi + 1] - np.einsum("gij,gj->gi", fm, states[mi])
            c += 0.5 * np.einsum("gi,gij,gj->", e, lam_cv, e)
        return c

    def system(poses, states):
        rows, cols, vals = [], [], []

        def add(r, c, v):
            rows.append(np.broadcast_to(r, v.shape).ravel())
            cols.append(np.broadcast_to(c, v.shape).ravel())
            vals.append(v.ravel())

        g = np.zeros(dim)
        hss = np.tile(np.diag(prior_w), (f, 1, 1))
        gs = states * prior_w
        hpp = np.zeros((3 * m, 3 * m))
        for n in names:
            ok = use[n]
            h, jp, js = measurement_model_pose(poses[n], states[ok])
            e = residual(h, meas_f[n][ok]) / sigmas
            w = _kernel_weight(np.linalg.norm(e, axis=1), robust, k)
            js = js / sigmas[:, None]
            ew = e * w[:, None]
            hss[ok] += np.einsum("kri,k,krj->kij", js, w, js)
            gs[ok] += np.einsum("kri,kr->ki", js, ew)
            if n != ref:
                i = others.index(n)
                jp = jp / sigmas[:, None]
                sl = slice(3 * i, 3 * i + 3)
                hpp[sl, sl] += np.einsum("kri,k,krj->ij", jp, w, jp)
                g[p0 + 3 * i:p0 + 3 * i + 3] += np.einsum("kri,kr->i", jp, ew)
                hps = np.einsum("kri,k,krj->kij", jp, w, js)  # (K, 3, 4)
                prow = (p0 + 3 * i + np.arange(3))[None, :, None]
                scol = sidx[ok][:, None, :]
                add(prow, scol, hps)
                add(np.swapaxes(scol, 1, 2), np.swapaxes(prow, 1, 2), np.swapaxes(hps, 1, 2))
        if mi is not None:
            e = states[mi + 1] - np.einsum("gij,gj->gi", fm, states[mi])
            le = np.einsum("gij,gj->gi", lam_cv, e)
            hss[mi] += np.einsum("gki,gkl,glj->gij", fm, lam_cv, fm)
            hss[mi + 1] += lam_cv
            off = -np.einsum("gki,gkj->gij", fm, lam_cv)  # d(k) x d(k+1) block
            gs[mi] -= np.einsum("gki,gk->gi", fm, le)
            gs[mi + 1] += le
            add(sidx[mi][:, :, None], sidx[mi + 1][:, None, :], off)
            add(sidx[mi + 1][:, :, None], sidx[mi][:, None, :], np.swapaxes(off, 1, 2))
        add(sidx[:, :, None], sidx[:, None, :], hss)
        if m:
            pr = p0 + np.arange(3 * m)
            add(pr[:, None], pr[None, :], hpp)
        g[:s0] = gs.ravel()
        hmat = sp.csc_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                             shape=(dim, dim))
        return hmat, g

    def apply(poses, states, delta):
        new = dict(poses)
        for i, n in enumerate(others):
            new[n] = pose_array(to_pose2(poses[n]).retract(delta[p0 + 3 * i:p0 + 3 * i + 3]))
        return new, states + delta[:s0].reshape(f, 4)

    if _system_only:  # for the tests: the linear system against GTSAM's
        return system(poses, states)
    lam, nu = 1e-4, 2.0
    cost = cost_of(poses, states)
    for _ in range(max_steps):
        hmat, g = system(poses, states)
        diag = sp.diags(np.maximum(hmat.diagonal(), 1e-12), format="csc")
        improved = False
        for _ in range(12):
            try:
                delta = -spla.spsolve(hmat + lam * diag, g, permc_spec="MMD_AT_PLUS_A")
            except RuntimeError:
                delta = np.full(dim, np.nan)
            if not np.all(np.isfinite(delta)):
                lam, nu = lam * nu, nu * 2.0
                continue
            new_poses, new_states = apply(poses, states, delta)
            new_cost = cost_of(new_poses, new_states)
            predicted = -(g @ delta + 0.5 * delta @ (hmat @ delta))
            rho = (cost - new_cost) / max(predicted, 1e-300)
            if new_cost <= cost and rho > 0:
                # Nielsen's damping update (as in Madsen, Nielsen & Tingleff)
                lam *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
                nu = 2.0
                improved = True
                break
            lam, nu = lam * nu, nu * 2.0
        if not improved:
            break
        done = (cost - new_cost) <= tol * max(cost, 1.0)
        poses, states, cost = new_poses, new_states, new_cost
        if done:
            break
    return poses, states


def _initial_poses(meas_f, names, ref, min_common_frames, min_spread_m):
    """Trimmed closed forms between every node pair with enough common frames,
    stitched by the pose graph."""
    local = {n: detection_to_local(meas_f[n][:, 0], meas_f[n][:, 1]) for n in names}
    edges, failures = [], {}
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            ok = np.isfinite(meas_f[a][:, 0]) & np.isfinite(meas_f[b][:, 0])
            if ok.sum() < min_common_frames:
                failures[f"{a}-{b}"] = f"{int(ok.sum())} common frames"
                continue
            try:
                cal, _ = trimmed_closed_form(local[a][ok], local[b][ok],
                                             min_common_frames=min_common_frames,
                                             min_spread_m=min_spread_m)
            except CalibrationError as exc:
                failures[f"{a}-{b}"] = str(exc)
                continue
            edges.append(PoseEdge.from_pairwise(a, b, cal))
    if not edges:
        raise CalibrationError("no node pair gives a closed-form starting pose: "
                               + "; ".join(f"{k}: {v}" for k, v in failures.items()))
    pg = pose_graph_calibration([ref] + [n for n in names if n != ref], edges, failures=failures)
    return dict(pg.poses), pg.unreachable


def _whitened_sq(state, pose, z, sigmas):
    h, _ = measurement_model(state, pose)
    e = residual(h, z) / sigmas
    return np.sum(e**2, axis=-1)


def joint_calibration(
    detections: Mapping[str, Detections],
    *,
    reference: str | None = None,
    initial_poses: Mapping[str, ArrayLike] | None = None,
    sigmas: ArrayLike = PAPER_SIGMAS,
    robust: Literal["huber", "cauchy"] | None = "cauchy",
    robust_k: float | None = None,
    motion: bool = False,
    frame_period_s: float | None = None,
    sigma_a_mps2: float = 1.0,
    max_motion_gap_frames: int = 3,
    state_prior_sigmas: ArrayLike = (1e3, 1e3, 3.5, 3.5),
    outlier_probability: float = 1e-3,
    min_common_frames: int = DEFAULT_MIN_COMMON_FRAMES,
    min_spread_m: float = DEFAULT_MIN_SPREAD_M,
    max_pose_variance: float = 1.0,
    max_pose_condition: float = 1e4,
    max_iterations: int = 50,
    presolve: bool = True,
    state_covariances: bool = False,
) -> JointCalibration:
    """Refine node poses jointly with the target's states (module doc).

    Parameters
    ----------
    detections : name -> Detections (or ``(frame (K,), measurements (K, 3))``)
        One detection of the common target per node per frame, frames
        already corrected for each node's lag. The first node is the
        reference unless ``reference`` names another.
    initial_poses : name -> (3,), optional
        Starting poses (the reference's is ignored); by default the trimmed
        closed form (and a pose graph for N > 2).
    sigmas : (3,) noise of ``(range_m, omega_rad, doppler_mps)``.
    robust, robust_k : kernel against ghost detections (None: Gaussian).
        Default k: Huber 1.345, Cauchy 2.5 (on the whitened 3-vector norm).
    motion : add constant-velocity factors between consecutive frames no
        more than ``max_motion_gap_frames`` apart; needs ``frame_period_s``.
    sigma_a_mps2 : white-acceleration sigma of the motion factors.
    state_prior_sigmas : (4,) sigmas of the zero-mean state prior.
    outlier_probability : a detection whose whitened squared residual exceeds
        the chi-square(3) ``1 - outlier_probability`` quantile is an outlier.
    min_common_frames : fewer frames seen by two nodes raise CalibrationError.
    max_pose_variance : a pose marginal variance (m^2 or rad^2) above this
        means that the pose is not determined: ``success=False``.
    max_pose_condition : so does an eigenvalue of a pose covariance more
        than this times its smallest (a standing target leaves S2 free to
        turn about it, up to the faint hold of the velocity prior through the
        Doppler: variances of 1e-6 against 0.2 in a test).
    presolve : run the numpy Schur-complement Gauss-Newton (same models,
        without motion factors) before each GTSAM LM pass; LM then needs one
        or two iterations. False: LM from the closed form (slower, same
        optimum).
    state_covariances : also return each frame's state marginal (slow for
        long sequences; NaN otherwise).

    Returns
    -------
    JointCalibration
    """
    dets = _detections_table(detections)
    names = list(dets)
    if len(names) < 2:
        raise CalibrationError(f"a calibration needs at least two nodes, got {names!r}")
    ref = names[0] if reference is None else str(reference)
    if ref not in dets:
        raise ValidationError(f"reference={ref!r} is not one of the nodes {names!r}")
    sig = check_positive(check_shape(as_float_array(sigmas, "sigmas"), (3,), "sigmas"), "sigmas")
    prior_sig = check_positive(check_shape(as_float_array(state_prior_sigmas, "state_prior_sigmas"),
                                           (4,), "state_prior_sigmas"), "state_prior_sigmas")
    if robust not in (None, "huber", "cauchy"):
        raise ValidationError(f"robust={robust!r} must be None, 'huber' or 'cauchy'")
    if motion and frame_period_s is None:
        raise ValidationError("motion=True needs frame_period_s")
    if not 0 < outlier_probability < 1:
        raise ValidationError(f"outlier_probability must lie in (0, 1), got {outlier_probability!r}")

    # Frames seen by at least two nodes; NaN rows where a node saw nothing.
    all_frames = np.unique(np.concatenate([d[0] for d in dets.values()]))
    seen = np.zeros((len(names), all_frames.size), dtype=bool)
    for i, n in enumerate(names):
        seen[i] = np.isin(all_frames, dets[n][0])
    frames = all_frames[seen.sum(0) >= 2]
    if frames.size < max(min_common_frames, 3):
        raise CalibrationError(f"too few frames seen by two nodes: {frames.size} < "
                               f"min_common_frames={max(min_common_frames, 3)}")
    f = frames.size
    meas_f = {}
    for n in names:
        z = np.full((f, 3), np.nan)
        idx = np.searchsorted(dets[n][0], frames)
        idx = np.clip(idx, 0, dets[n][0].size - 1)
        hit = dets[n][0][idx] == frames
        z[hit] = dets[n][1][idx[hit]]
        meas_f[n] = z

    # Initial poses.
    if initial_poses is None:
        init, unreachable = _initial_poses(meas_f, names, ref, min_common_frames, min_spread_m)
    else:
        init = {}
        for n in names:
            if n == ref:
                continue
            if n not in initial_poses:
                raise ValidationError(f"initial_poses has no pose for node {n!r}")
            init[n] = check_finite(check_shape(as_float_array(initial_poses[n],
                                                              f"initial_poses[{n!r}]"), (3,),
                                               f"initial_poses[{n!r}]"), f"initial_poses[{n!r}]")
        unreachable = ()
    init[ref] = np.zeros(3)
    active = [n for n in names if n not in unreachable]
    # Frames still seen by two active nodes.
    n_seen = sum(np.isfinite(meas_f[n][:, 0]).astype(int) for n in active)
    keep = n_seen >= 2
    frames = frames[keep]
    meas_f = {n: meas_f[n][keep] for n in active}
    f = frames.size
    if f < max(min_common_frames, 3):
        raise CalibrationError(f"too few frames seen by two calibrated nodes: {f}")

    x0 = _initial_states(meas_f, init, active, sig, prior_sig[2])
    pose_key = {n: gtsam.symbol("x", i) for i, n in enumerate(active)}
    state_key = [gtsam.symbol("v", k) for k in range(f)]
    k_default = {"huber": 1.345, "cauchy": 2.5}
    noise_robust = measurement_noise(sig, robust, None if robust is None else
                                     (robust_k if robust_k is not None else k_default[robust]))
    noise_gauss = measurement_noise(sig)

    def build(noise, use):
        g = gtsam.NonlinearFactorGraph()
        for n in active:
            z = meas_f[n]
            for k in np.flatnonzero(use[n]):
                if n == ref:
                    g.add(node_measurement_factor(state_key[k], np.zeros(3), z[k], noise))
                else:
                    g.add(pose_measurement_factor(pose_key[n], state_key[k], z[k], noise))
        for k in range(f):
            g.add(state_prior_factor(state_key[k], np.zeros(4), prior_sig))
        if motion:
            gaps = np.diff(frames)
            for k in np.flatnonzero(gaps <= max_motion_gap_frames):
                g.add(constant_velocity_factor(state_key[k], state_key[k + 1],
                                               float(gaps[k]) * float(frame_period_s),
                                               sigma_a_mps2))
        return g

    def to_values(poses, states):
        v = gtsam.Values()
        for n in active:
            if n != ref:
                v.insert(pose_key[n], to_pose2(poses[n]))
        for k in range(f):
            v.insert(state_key[k], states[k])
        return v

    def current(res):
        poses = {n: (np.zeros(3) if n == ref else pose_array(res.atPose2(pose_key[n])))
                 for n in active}
        states = np.array([res.atVector(state_key[k]) for k in range(f)])
        return poses, states

    has = {n: np.isfinite(meas_f[n][:, 0]) for n in active}
    kk = None if robust is None else (robust_k if robust_k is not None else k_default[robust])
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(int(max_iterations))
    graph = build(noise_robust, has)
    start = {n: init[n] for n in active}
    initial_error = float(graph.error(to_values(start, x0)))
    motion_spec = None
    if motion:
        gaps = np.diff(frames)
        mi = np.flatnonzero(gaps <= max_motion_gap_frames)
        motion_spec = (mi, gaps[mi] * float(frame_period_s), float(sigma_a_mps2))
    if presolve:
        start, x0 = _presolve(meas_f, start, x0, active, ref, sig, prior_sig, robust,
                              kk if kk is not None else 1.0, motion=motion_spec)
    opt = gtsam.LevenbergMarquardtOptimizer(graph, to_values(start, x0), params)
    result = opt.optimize()
    iterations = int(opt.iterations())
    poses, states = current(result)
    threshold = chi2.ppf(1.0 - outlier_probability, 3)
    outliers = {}
    for n in active:
        e2 = np.full(f, 0.0)
        e2[has[n]] = _whitened_sq(states[has[n]], poses[n], meas_f[n][has[n]], sig)
        outliers[n] = has[n] & (e2 > threshold)
    final_graph = graph
    if robust is not None:
        inl = {n: has[n] & ~outliers[n] for n in active}
        final_graph = build(noise_gauss, inl)
        if presolve:
            poses, states = _presolve(meas_f, poses, states, active, ref, sig, prior_sig,
                                      None, 1.0, use=inl, motion=motion_spec)
        opt2 = gtsam.LevenbergMarquardtOptimizer(final_graph, to_values(poses, states), params)
        result = opt2.optimize()
        iterations += int(opt2.iterations())
        poses, states = current(result)
    final_error = float(final_graph.error(result))

    covs: dict[str, NDArray] = {ref: np.zeros((3, 3))}
    state_covs = np.full((f, 4, 4), np.nan)
    unobservable: dict[str, NDArray] = {}
    success, notes = True, []
    try:
        marg = gtsam.Marginals(final_graph, result)
        for n in active:
            if n != ref:
                c = marg.marginalCovariance(pose_key[n])
                covs[n] = 0.5 * (c + c.T)
        if state_covariances:
            for k in range(f):
                c = marg.marginalCovariance(state_key[k])
                state_covs[k] = 0.5 * (c + c.T)
        for n in active:
            if n == ref:
                continue
            w, v = np.linalg.eigh(covs[n])
            bad = (w > max_pose_variance) | (w > max_pose_condition * max(w.min(), 1e-300))
            if np.any(bad):
                unobservable[n] = v[:, bad].T
    except RuntimeError as exc:
        notes.append(f"marginals failed ({str(exc).splitlines()[0]})")
        covs.update(_schur_covariances(final_graph, result, active, ref, pose_key, state_key,
                                       unobservable, max_pose_condition))
    if unobservable:
        success = False
        for n, dirs in unobservable.items():
            txt = ", ".join("(" + ", ".join(f"{c:+.2f}" for c in d) + ")" for d in dirs)
            notes.append(f"pose of {n} is not observable along {txt} (dx_b, dy_b, dphi)")
    if unreachable:
        success = False
        notes.append(f"no common frames linking {', '.join(unreachable)} to {ref}")
    n_out = sum(int(o.sum()) for o in outliers.values())
    msg = (f"joint calibration of {len(active)} nodes on {f} frames, {n_out} outlier "
           f"detection(s), {iterations} LM iterations")
    if notes:
        msg += "; " + "; ".join(notes)
    return JointCalibration(
        reference=ref, poses=poses, covariances=covs,
        initial_poses={n: np.asarray(init[n], dtype=float) for n in active}, frames=frames,
        states=states, state_covariances=state_covs, outliers=outliers, success=success,
        message=msg, iterations=iterations, initial_error=initial_error, final_error=final_error,
        unobservable=unobservable, unreachable=tuple(unreachable))


def _schur_covariances(graph, values, active, ref, pose_key, state_key, unobservable,
                       condition):
    """Pose information by a dense Schur complement of the linearized graph,
    for a singular system: the eigen-directions whose information is below
    ``1 / condition`` of the largest are unobservable; the covariance is the
    inverse on the rest, with ``inf`` on the diagonal of every component a
    null direction touches (NaN off the diagonal there)."""
    others = [n for n in active if n != ref]
    order = gtsam.Ordering()
    for n in others:
        order.push_back(pose_key[n])
    for k in state_key:
        order.push_back(k)
    lam, _ = graph.linearize(values).hessian(order)
    p = 3 * len(others)
    a, b, c = lam[:p, :p], lam[:p, p:], lam[p:, p:]
    schur = a - b @ np.linalg.lstsq(c, b.T, rcond=None)[0]
    schur = 0.5 * (schur + schur.T)
    w, v = np.linalg.eigh(schur)
    null = w <= max(w.max(), 1e-300) / condition
    keep = ~null
    cov_all = (v[:, keep] / w[keep]) @ v[:, keep].T  # inverse on the observable part
    covs = {}
    for i, n in enumerate(others):
        rows = slice(3 * i, 3 * i + 3)
        cov = cov_all[rows, rows].copy()
        dirs = v[rows][:, null].T  # (m, 3) this node's part of each null vector
        dirs = dirs[np.linalg.norm(dirs, axis=1) > 1e-3]
        if dirs.size:
            unobservable[n] = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
            touched = np.any(np.abs(unobservable[n]) > 1e-3, axis=0)
            cov[touched, :] = np.nan
            cov[:, touched] = np.nan
            cov[touched, touched] = np.inf
        covs[n] = cov
    return covs
