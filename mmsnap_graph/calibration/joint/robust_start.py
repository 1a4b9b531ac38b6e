"""Starting point of the joint calibration graph: robust closed-form poses
(least median of squares, then trimmed refits), stitched by a pose graph when
N > 2, and each frame's target state from the detections at those poses.
"""

from __future__ import annotations

import dataclasses
from typing import Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from factors.models import detection_to_local, local_to_global, measurement_model, residual

from ...errors import CalibrationError
from ...data.calibration import PairwiseCalibration
from ...data.calibration_facts import SolveBrokeDown
from ..pairwise.closed_form import closed_form_calibration, closed_form_pose
from ..pairwise.pose_graph import pose_graph_calibration

__all__ = ["trimmed_closed_form", "starting_poses", "starting_states"]


def _residuals(pose, points_a_m, points_b_m):
    c, s = np.cos(pose[2]), np.sin(pose[2])
    bx, by = points_b_m[:, 0], points_b_m[:, 1]
    return np.hypot(points_a_m[:, 0] - (pose[0] + c * bx - s * by),
                    points_a_m[:, 1] - (pose[1] + s * bx + c * by))


def trimmed_closed_form(points_a_m: NDArray, points_b_m: NDArray, *, n_rounds: int = 3,
                        trim_factor: float = 2.5, n_subsets: int = 200, subset_size: int = 6,
                        seed: int = 0, **kwargs) -> tuple[PairwiseCalibration, NDArray]:
    """A robust closed form for starting poses: least median of squares over
    ``n_subsets`` random ``subset_size``-frame subsets (the bare closed form
    on each; robust to up to half the frames being ghosts), then the closed
    form refitted ``n_rounds`` times on the frames whose alignment residual
    is below ``trim_factor`` times the median residual. Deterministic
    (``seed``). ``kwargs`` go to :func:`closed_form_calibration`. Returns
    ``(PairwiseCalibration, inlier mask (K,))``."""
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


def starting_poses(measurements: Mapping[str, NDArray], names: Sequence[str], reference: str,
                   min_common_frames: int, min_spread_m: float
                   ) -> tuple[dict[str, NDArray], tuple[str, ...]]:
    """Trimmed closed forms between every node pair with enough common frames
    (``measurements`` name -> (F, 3), NaN rows where unseen), stitched by the
    pose graph anchored at ``reference``. Returns ``(poses, unreachable)``;
    raises :class:`CalibrationError` when no pair gives a pose."""
    local = {n: detection_to_local(measurements[n][:, 0], measurements[n][:, 1]) for n in names}
    edges, failures = [], {}
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            ok = np.isfinite(measurements[a][:, 0]) & np.isfinite(measurements[b][:, 0])
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
            edges.append(dataclasses.replace(cal, node_a=a, node_b=b))
    if not edges:
        raise CalibrationError("no node pair gives a closed-form starting pose: "
                               + "; ".join(f"{k}: {v}" for k, v in failures.items()))
    pg = pose_graph_calibration([reference] + [n for n in names if n != reference], edges,
                                failures=failures)
    if not pg.success:  # no poses at all: a typed error, not a missing key later
        why = (f"no path to {reference}: {', '.join(pg.unreachable)}" if pg.unreachable
               else "; ".join(f.reason for f in pg.facts_of(SolveBrokeDown)))
        raise CalibrationError(f"the closed-form starting poses: {pg.status.message} ({why})")
    return dict(pg.poses), pg.unreachable


def _refine_positions(measurements, poses, names, pos, sigmas, gn_steps):
    """A few Gauss-Newton steps per frame on range + spatial frequency with
    the poses held: each frame's position at its own optimum, so LM starts
    near the joint solution (vectorized over frames; 2x2 solves)."""
    f = pos.shape[0]
    w = np.array([1.0 / sigmas[0]**2, 1.0 / sigmas[1]**2])
    for _ in range(gn_steps):
        a = np.tile(np.eye(2) * 1e-9, (f, 1, 1))
        b = np.zeros((f, 2))
        state = np.concatenate([pos, np.zeros((f, 2))], axis=1)
        for n in names:
            z = measurements[n]
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
    return pos


def starting_states(measurements: Mapping[str, NDArray], poses: Mapping[str, NDArray],
                    names: Sequence[str], sigmas: NDArray, prior_v_sigma: float,
                    gn_steps: int = 3) -> NDArray:
    """(F, 4) target states at the given poses: the average of each node's
    detection mapped to global (docs/CONVENTIONS.md, initial values), refined
    by ``gn_steps`` Gauss-Newton steps on range and spatial frequency, and
    the velocity from the Dopplers by least squares regularized by a
    zero-mean prior of sigma ``prior_v_sigma``."""
    f = next(iter(measurements.values())).shape[0]
    pos_sum = np.zeros((f, 2))
    count = np.zeros(f)
    for n in names:
        z = measurements[n]
        ok = np.isfinite(z[:, 0])
        pos_sum[ok] += local_to_global(detection_to_local(z[ok, 0], z[ok, 1]), poses[n])
        count[ok] += 1
    pos = _refine_positions(measurements, poses, names, pos_sum / count[:, None], sigmas,
                            gn_steps)
    sigma_doppler = sigmas[2]
    a = np.tile(np.eye(2) / prior_v_sigma**2, (f, 1, 1))
    b = np.zeros((f, 2))
    for n in names:
        z = measurements[n]
        ok = np.isfinite(z[:, 0])
        d = pos[ok] - poses[n][:2]
        u = d / np.linalg.norm(d, axis=1, keepdims=True)
        a[ok] += np.einsum("ki,kj->kij", u, u) / sigma_doppler**2
        b[ok] += u * z[ok, 2:3] / sigma_doppler**2
    vel = np.linalg.solve(a, b[..., None])[..., 0]
    return np.concatenate([pos, vel], axis=1)
