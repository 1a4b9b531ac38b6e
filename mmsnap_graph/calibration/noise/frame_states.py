"""Each frame's least-squares target state from the nodes that see it, at
known poses (the noise estimators' inner solve; docs/CALIBRATION.md, "Noise
from the data")."""

from __future__ import annotations

from typing import Mapping

import numpy as np
from numpy.typing import NDArray

from factors.models import detection_to_global, measurement_model, residual

from ...data.recording import Detections

__all__ = ["solve_frame_states", "frame_table", "without_unsolved", "det_4x4"]

#: A frame's information whose smallest eigenvalue is below this fraction of
#: its largest is numerically singular (float64 keeps ~16 digits; a solve
#: there returns noise or raises): the frame is not solved.
SINGULAR_RCOND = 1e-13


def solve_information(info: NDArray, rhs: NDArray, psd: bool = False) -> tuple[NDArray, NDArray]:
    """``info^-1 rhs`` per frame and the frames solved ``(F,)``: NaN where
    the information is not finite or numerically singular (a coordinate
    whose weight dwarfs the others', e.g. ranges rounded to whole metres
    whose differences give a sigma of 1e-16 m), never a ``LinAlgError``.

    psd : the information is a sum of non-negatively weighted outer products
    (positive semi-definite): a frame whose determinant exceeds
    ``10 SINGULAR_RCOND trace^4`` is then well conditioned for sure (its smallest
    eigenvalue is at least ``det / trace^3``), and only the others need the
    eigenvalues (the decision is the same, for a seventh of the cost)."""
    if psd and info.shape[-1] == 4:
        # The determinant from the 2x2 minors of the rows: it is finite only
        # when every entry is (NaN and inf never return to a finite number
        # through +, - and *), so a frame it proves well conditioned needs
        # no check of its entries; the others are checked as they are.
        with np.errstate(over="ignore", under="ignore", invalid="ignore"):
            det = det_4x4(info)
            trace = info[:, 0, 0] + info[:, 1, 1] + info[:, 2, 2] + info[:, 3, 3]
            rest = ~(np.isfinite(det) & (det > 10.0 * SINGULAR_RCOND * trace ** 4))
        finite = np.ones(info.shape[0], dtype=bool)
        if rest.any():
            finite[rest] = np.isfinite(info[rest]).all(axis=(1, 2))
        ok = finite
        doubt = rest & finite
    else:
        finite = np.isfinite(info).all(axis=(1, 2))
        ok = finite
        doubt = finite
        if psd and finite.any():
            with np.errstate(over="ignore", under="ignore", invalid="ignore"):
                safe = np.where(finite[:, None, None], info, np.eye(info.shape[-1]))
                trace = np.trace(safe, axis1=1, axis2=2)
                doubt = finite & ~(np.linalg.det(safe) > 10.0 * SINGULAR_RCOND * trace ** 4)
    if doubt.any():
        lam = np.linalg.eigvalsh(info[doubt])
        ok = finite.copy()
        ok[doubt] = lam[:, 0] > SINGULAR_RCOND * np.abs(lam[:, -1])
    if ok.all():
        return np.linalg.solve(info, rhs), ok
    out = np.full(rhs.shape, np.nan)
    if ok.any():
        out[ok] = np.linalg.solve(info[ok], rhs[ok])
    return out, ok


def det_4x4(a: NDArray) -> NDArray:
    """(F,) determinants of (F, 4, 4) matrices in closed form (Laplace's
    expansion in the 2x2 minors of the first two rows and of the last two):
    a few elementwise products, against an LU factorization per frame."""
    a00, a01, a02, a03 = a[:, 0, 0], a[:, 0, 1], a[:, 0, 2], a[:, 0, 3]
    a10, a11, a12, a13 = a[:, 1, 0], a[:, 1, 1], a[:, 1, 2], a[:, 1, 3]
    a20, a21, a22, a23 = a[:, 2, 0], a[:, 2, 1], a[:, 2, 2], a[:, 2, 3]
    a30, a31, a32, a33 = a[:, 3, 0], a[:, 3, 1], a[:, 3, 2], a[:, 3, 3]
    s0, s1, s2 = a00 * a11 - a10 * a01, a00 * a12 - a10 * a02, a00 * a13 - a10 * a03
    s3, s4, s5 = a01 * a12 - a11 * a02, a01 * a13 - a11 * a03, a02 * a13 - a12 * a03
    c5, c4, c3 = a22 * a33 - a32 * a23, a21 * a33 - a31 * a23, a21 * a32 - a31 * a22
    c2, c1, c0 = a20 * a33 - a30 * a23, a20 * a32 - a30 * a22, a20 * a31 - a30 * a21
    return s0 * c5 - s1 * c4 + s2 * c3 + s3 * c2 - s4 * c1 + s5 * c0


def without_unsolved(w: NDArray, jac: NDArray, cov: NDArray) -> tuple[NDArray, NDArray, NDArray]:
    """The weights, Jacobians and covariances of :func:`solve_frame_states`
    with the frames it could not solve (NaN covariance) left out: weight 0,
    Jacobian and covariance 0, so that sums over frames skip them."""
    ok = np.all(np.isfinite(cov), axis=(1, 2))
    return (np.where(ok[:, None, None], w, 0.0), np.where(ok[:, None, None, None], jac, 0.0),
            np.where(ok[:, None, None], cov, 0.0))


def solve_frame_states(z: NDArray, poses: NDArray, w: NDArray, prior_w: NDArray,
                       iterations: int = 6) -> tuple[NDArray, NDArray, NDArray, NDArray]:
    """Gauss-Newton per frame, vectorized over frames.

    z : (F, N, 3) measurements (NaN = the node does not see the frame);
    poses : (N, 3); w : (F, N, 3) weights (inverse variances, 0 = left out);
    prior_w : (4,) information of a zero-mean prior on the state (a weak one
    keeps an unobserved velocity direction in place). Starts at the first
    observing node's detection. Returns states (F, 4), residuals (F, N, 3)
    (NaN where unseen), Jacobians (F, N, 3, 4) and covariances (F, 4, 4);
    a frame whose information is numerically singular has NaN state,
    residuals and covariance (:func:`without_unsolved` leaves it out).
    """
    f = z.shape[0]
    seen = np.isfinite(z[..., 0])
    first = np.argmax(seen, axis=1)
    zf = z[np.arange(f), first]
    x = np.zeros((f, 4))
    x[:, :2] = detection_to_global(zf[:, 0], zf[:, 1], poses[first])
    zz = np.where(np.isfinite(z), z, 0.0)
    prior = np.diag(prior_w)
    # weights and prior >= 0: every frame's information is semi-definite
    psd = bool((w >= 0).all() and (np.asarray(prior_w) >= 0).all())
    for _ in range(iterations):
        h, jac = measurement_model(x[:, None, :], poses[None])
        e = np.where(seen[..., None], residual(h, zz), 0.0)
        info = np.einsum("fnri,fnr,fnrj->fij", jac, w, jac) + prior
        grad = np.einsum("fnri,fnr,fnr->fi", jac, w, e)
        x = x - solve_information(info, grad[..., None], psd)[0][..., 0]
    h, jac = measurement_model(x[:, None, :], poses[None])
    e = np.where(seen[..., None], residual(h, zz), np.nan)
    info = np.einsum("fnri,fnr,fnrj->fij", jac, w, jac) + prior
    cov, ok = solve_information(info, np.broadcast_to(np.eye(4), info.shape), psd)
    x[~ok] = np.nan
    e[~ok] = np.nan
    return x, e, jac, cov


def frame_table(detections: Mapping[str, Detections], names) -> tuple[NDArray, NDArray]:
    """Measurements ``(F, N, 3)`` (NaN = not seen) of the frames that at
    least two nodes see with exactly one centroid each."""
    single = {}
    for n in names:
        det = detections[n]
        frames, counts = np.unique(det.frame, return_counts=True)
        single[n] = frames[counts == 1]
    all_frames = np.unique(np.concatenate([single[n] for n in names]))
    seen = np.array([np.isin(all_frames, single[n]) for n in names]).T
    frames = all_frames[seen.sum(axis=1) >= 2]
    z = np.full((frames.size, len(names), 3), np.nan)
    for j, n in enumerate(names):
        det = detections[n]
        rows = np.isin(det.frame, frames) & np.isin(det.frame, single[n])
        z[np.searchsorted(frames, det.frame[rows]), j] = det.measurements[rows]
    return frames, z
