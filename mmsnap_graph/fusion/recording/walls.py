"""Walls learned from multipath images (docs/ROBUST.md, "Learned walls"):
a radar cannot see a person through a wall.

A radar sees a person P directly and, via a flat wall, an image of P farther
away. Two images are common (docs/TI.md, "Static scene and ghosts"):

- the **mirror image** M of P through the wall (the path radar -> wall -> P
  -> wall -> radar): the wall is the perpendicular bisector of P and M;
- the **one-bounce image** (radar -> P -> wall -> radar): at the mean of the
  two paths, ``(|P - S| + |M - S|) / 2`` from the radar S, along the bearing
  of M. From such an image G the mirror image is ``M = S + (2 |G - S| -
  |P - S|) u``, ``u`` the unit vector from S to G.

A node's image G of a person is a fused row seen by no more nodes than a
row P of its frame (the person, walking: at least :data:`WALL_MOVING_MPS`;
radars on the same side of a wall see its mirror image as one consistent
target, fused from them all like the person),
farther from the node than P, whose radial speed
(its Doppler) is the one its kind predicts from P's velocity mirrored through
the wall (within :data:`WALL_DOPPLER_SIGMAS` of both rows' velocity
covariances): a second person walking on their own rarely is. Every such pair
proposes its wall line (one per image kind); a wall is a line proposed in at
least :data:`WALL_MIN_FRAMES` distinct frames (within
:data:`WALL_ANGLE_TOL_RAD` and :data:`WALL_OFFSET_TOL_M`), with the node on
its room side, and behind which (almost) no person seen by two or more nodes
ever stands: at most :data:`WALL_MAX_CROSSING` of those rows, not counting the
images it explains. A room's wall is common to its nodes: a line that the
images of two or more nodes propose together in at least
:data:`WALL_MIN_FRAMES` frames (with the same crossing test) is a wall of
each of them too (two radars facing each other see a side wall's images in
different frames, too few for either alone). Of two walls of a node that
explain the same images (one per kind, or its own and the common one), the
one proposed in more frames is kept.

:func:`beyond_learned_walls` flags the successful rows that lie more than
:data:`WALL_MARGIN_M` beyond a wall of every node that sees them, where the
line from the node to the row crosses the wall within
:data:`WALL_EXTENT_M` of the images that taught it (a bearing where no image
was seen flags nothing). A recording without multipath images (or with too
few) learns no wall and flags nothing.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ...errors import ValidationError

__all__ = ["LearnedWall", "learn_walls", "beyond_learned_walls", "WALL_MIN_FRAMES",
           "WALL_ANGLE_TOL_RAD", "WALL_OFFSET_TOL_M", "WALL_DOPPLER_SIGMAS",
           "WALL_DOPPLER_FLOOR_MPS", "WALL_MOVING_MPS", "WALL_MARGIN_M", "WALL_EXTENT_M",
           "WALL_MAX_CROSSING"]

#: Distinct frames whose images must propose one wall (0.5 s at 20 fps): a
#: wall is there all the time; two people are rarely in mirror positions.
WALL_MIN_FRAMES = 10
#: Proposals within this angle (of the wall's normal) ...
WALL_ANGLE_TOL_RAD = float(np.deg2rad(10.0))
#: ... and this offset (m) are one wall (a centroid's scatter, 0.1-0.2 m).
WALL_OFFSET_TOL_M = 0.3
#: A row is flagged this far beyond the wall (m): half a body, so that a
#: person standing at the wall is never behind it.
WALL_MARGIN_M = 0.25
#: A wall reaches this far (m) beyond the images that taught it, along it.
WALL_EXTENT_M = 1.0
#: An image's radial speed must be its kind's prediction within this many
#: sigmas (of both rows' velocity covariances) ...
WALL_DOPPLER_SIGMAS = 3.0
#: ... and this floor (m/s): about a TI Doppler bin (0.12 m/s at 77 GHz with
#: the out-of-box chirps).
WALL_DOPPLER_FLOOR_MPS = 0.15
#: The person must walk (m/s): the images of someone standing still have no
#: Doppler to tell them from static clutter.
WALL_MOVING_MPS = 0.2
#: Fraction of the rows seen by two or more nodes that may stand behind a
#: wall (not explained as its images): a misassociated row now and then.
WALL_MAX_CROSSING = 0.005

_BIN_RAD = WALL_ANGLE_TOL_RAD / 2
_BIN_M = WALL_OFFSET_TOL_M / 2


@dataclass(frozen=True, slots=True)
class LearnedWall:
    """One node's wall: the points ``x`` with ``normal . x = offset_m`` (the
    normal points out of the room, away from the node), known along the wall
    (``tangent . x``, tangent = normal turned +90 deg) between ``along_m``
    (min, max) of its images; ``frames`` that proposed it; ``images`` rows it
    explains."""

    node: int
    normal_rad: float
    offset_m: float
    along_m: tuple[float, float]
    frames: int
    images: int

    @property
    def normal(self) -> NDArray:
        return np.array([np.cos(self.normal_rad), np.sin(self.normal_rad)])

    def text(self, node_names) -> str:
        n = self.normal
        return (f"{node_names[self.node]}: {n[0]:+.2f} x {n[1]:+.2f} y = {self.offset_m:.2f} m "
                f"({self.frames} frames)")


def wall_line(p: NDArray, m: NDArray) -> tuple[NDArray, NDArray]:
    """Bisectors of P (K, 2) and M (K, 2): normal angle (from P to M), offset."""
    d = m - p
    n = d / np.linalg.norm(d, axis=1, keepdims=True)
    return np.arctan2(n[:, 1], n[:, 0]), np.einsum("ij,ij->i", n, (p + m) / 2)


def wall_crossing(node: NDArray, xy: NDArray, n: NDArray, offset: NDArray) -> NDArray:
    """(K,) where the line of sight from ``node`` to ``xy`` (K, 2) crosses the
    lines ``n . x = offset`` (n (K, 2) or (2,)), as a position along them
    (tangent = n turned +90 deg); inf where it does not reach them."""
    n = np.broadcast_to(n, xy.shape)
    toward = np.einsum("ij,ij->i", n, xy - node)
    lam = np.divide(offset - n @ node, toward, out=np.full(len(xy), np.inf),
                    where=toward > 0)
    reach = np.isfinite(lam)
    at = node + np.where(reach, lam, 0.0)[:, None] * (xy - node)
    return np.where(reach, -n[:, 1] * at[:, 0] + n[:, 0] * at[:, 1], np.inf)


def speeds_agree(u_g, u_p, n, state, cov, gs, ps, one_bounce: bool) -> NDArray:
    """(K,) the image's radial speed (its Doppler, seen from the node: unit
    vectors ``u_g``, ``u_p`` to the image and the person) is the one its
    kind predicts from the person's velocity mirrored through the wall
    (normal ``n``): ``u_g . R v_P`` for the mirror image, the mean of
    ``u_p . v_P`` and that for the one-bounce image; within
    :data:`WALL_DOPPLER_SIGMAS` of both rows' velocity covariances (and
    :data:`WALL_DOPPLER_FLOOR_MPS`)."""
    v_g, v_p = state[gs, 2:], state[ps, 2:]
    # R v = v - 2 (n . v) n, and R is its own transpose.
    r_u = u_g - 2 * np.einsum("ij,ij->i", n, u_g)[:, None] * n
    grad = (r_u + u_p) / 2 if one_bounce else r_u
    predicted = np.einsum("ij,ij->i", grad, v_p)
    var = (np.einsum("ij,ijk,ik->i", u_g, cov[gs, 2:, 2:], u_g)
           + np.einsum("ij,ijk,ik->i", grad, cov[ps, 2:, 2:], grad) + WALL_DOPPLER_FLOOR_MPS ** 2)
    miss = np.einsum("ij,ij->i", u_g, v_g) - predicted
    return miss ** 2 <= WALL_DOPPLER_SIGMAS ** 2 * var


def _pairs(frame: NDArray, ok: NDArray, image_ok: NDArray) -> tuple[NDArray, NDArray, NDArray]:
    """Every (image row, person row) of one frame: ``(g, p, frame group)``,
    the frames in order, each frame's images in row order and, for each,
    the frame's people in row order (the order a loop over the frames and a
    meshgrid of each frame's images and people gives)."""
    order = np.argsort(frame, kind="stable")
    sorted_frame = frame[order]
    group = np.cumsum(np.r_[False, sorted_frame[1:] != sorted_frame[:-1]])
    images, image_group = order[image_ok[order]], group[image_ok[order]]
    people, people_group = order[ok[order]], group[ok[order]]
    n_groups = int(group[-1]) + 1 if group.size else 0
    per_group = np.bincount(people_group, minlength=n_groups)
    first = np.cumsum(per_group) - per_group  # each group's first person
    reps = per_group[image_group]  # each image pairs with its frame's people
    g = np.repeat(images, reps)
    within = np.arange(g.size) - np.repeat(np.cumsum(reps) - reps, reps)
    p = people[np.repeat(first[image_group], reps) + within]
    return g, p, np.repeat(image_group, reps)


def wall_proposals(frame, state, cov, ok, image_ok, seen, poses, body_m):
    """Wall proposals: (row of the image, node, normal angle, offset, along,
    frame), in frame order, then node, then image kind, then pair; every
    frame's pairs at once (the arithmetic of each pair is elementwise)."""
    xy = state[:, :2]
    n_seen = seen.sum(axis=1)
    g, p, pg = _pairs(frame, ok, image_ok)
    keep = ((g != p) & (n_seen[g] <= n_seen[p]) & (np.hypot(*(xy[g] - xy[p]).T) >= body_m)
            & (np.hypot(*state[p, 2:].T) >= WALL_MOVING_MPS))
    g, p, pg = g[keep], p[keep], pg[keep]
    out, keys = [], []
    for s in range(poses.shape[0]):
        node = poses[s, :2]
        sel = seen[g, s]
        gs, ps, gk = g[sel], p[sel], pg[sel]
        r_g, r_p = np.hypot(*(xy[gs] - node).T), np.hypot(*(xy[ps] - node).T)
        far = r_p < r_g
        gs, ps, gk, r_g, r_p = gs[far], ps[far], gk[far], r_g[far], r_p[far]
        if gs.size == 0:
            continue
        u_g, u_p = (xy[gs] - node) / r_g[:, None], (xy[ps] - node) / r_p[:, None]
        for one_bounce in (False, True):
            m = node + ((2 * r_g - r_p) / r_g)[:, None] * (xy[gs] - node) if one_bounce \
                else xy[gs]
            ang, off = wall_line(xy[ps], m)
            n = np.stack([np.cos(ang), np.sin(ang)], axis=1)
            k = ((n @ node < off) & (np.einsum("ij,ij->i", n, u_g) > 0)
                 & speeds_agree(u_g, u_p, n, state, cov, gs, ps, one_bounce))
            along = wall_crossing(node, xy[gs], n, off)
            out.append(np.stack([gs[k], np.full(k.sum(), s), ang[k], off[k], along[k],
                                 frame[gs[k]]], axis=1))
            keys.append(np.stack([gk[k], np.full(k.sum(), 2 * s + one_bounce)], axis=1))
    if not out:
        return np.zeros((0, 6))
    keys = np.concatenate(keys)
    return np.concatenate(out)[np.lexsort((keys[:, 1], keys[:, 0]))]


def _near(props: NDArray, ang: float, off: float, scale: float = 1.0) -> NDArray:
    da = np.abs((props[:, 2] - ang + np.pi) % (2 * np.pi) - np.pi)
    return (da <= scale * WALL_ANGLE_TOL_RAD) & (np.abs(props[:, 3] - off)
                                                 <= scale * WALL_OFFSET_TOL_M)


def _checked(frame, state, covariance, ok, seen, poses):
    """The arrays of :func:`learn_walls`, their shapes checked."""
    frame = np.asarray(frame)
    state = np.asarray(state, dtype=float)
    cov = np.nan_to_num(np.asarray(covariance, dtype=float), nan=0.0)
    ok, seen = np.asarray(ok, dtype=bool), np.asarray(seen, dtype=bool)
    poses = np.asarray(poses, dtype=float)
    k = frame.shape[0] if frame.ndim == 1 else -1
    n = poses.shape[0] if poses.ndim == 2 and poses.shape[1] == 3 else -1
    for name, arr, shape in (("frame", frame, (k,)), ("state", state, (k, 4)),
                             ("covariance", cov, (k, 4, 4)), ("ok", ok, (k,)),
                             ("seen", seen, (k, n)), ("poses", poses, (n, 3))):
        if k < 0 or n < 0 or arr.shape != shape:
            raise ValidationError(f"learned walls: {name} has shape {arr.shape}; frame (K,), "
                                  "state (K, 4), covariance (K, 4, 4), ok (K,), seen (K, N) "
                                  "and poses (N, 3) are needed")
    return frame, state, cov, ok, seen, poses


def learn_walls(frame: NDArray, state: NDArray, covariance: NDArray, ok: NDArray, seen: NDArray,
                poses: NDArray, *, body_m: float,
                image_ok: NDArray | None = None) -> list[LearnedWall]:
    """The walls of each node (module doc).

    frame : (K,) int; state : (K, 4); covariance : (K, 4, 4) (NaN: unknown,
    taken as 0: the Doppler floor alone); ok : (K,) bool, the successful rows
    (the people, and the rows a wall must not stand in front of); seen :
    (K, N) bool, the nodes each row was fused from; poses : (N, 3);
    image_ok : (K,) bool, the rows that may be images (default ``ok``; rows
    the motion check flagged are images too).
    """
    frame, state, cov, ok, seen, poses = _checked(frame, state, covariance, ok, seen, poses)
    if not (np.isfinite(body_m) and body_m > 0):
        raise ValidationError(f"body_m={body_m!r} must be finite and > 0 (m)")
    image_ok = ok if image_ok is None else np.asarray(image_ok, dtype=bool).reshape(ok.shape)
    xy = state[:, :2]
    props = wall_proposals(frame, state, cov, ok, image_ok, seen, poses, body_m)
    confirmed = ok & (seen.sum(axis=1) >= 2)
    # The room's walls are common to its nodes: two radars facing each other
    # see a side wall's images in different frames, too few for either alone.
    # A line that the images of two or more nodes propose together is a wall
    # of each of them, beside the lines each node's images propose alone.
    index = _LineIndex(props)
    pooled = [line for line in _lines(props, xy, confirmed, poses,
                                      index.counts(np.arange(len(props))))
              if np.unique(line.props[:, 1]).size >= 2]
    walls: list[LearnedWall] = []
    for s in range(poses.shape[0]):
        rows = np.flatnonzero(props[:, 1] == s)
        mine = _lines(props[rows], xy, confirmed, poses, index.counts(rows))
        for line in _one_per_image(mine + [p for p in pooled if np.any(p.props[:, 1] == s)]):
            along = line.props[:, 4]
            walls.append(LearnedWall(node=s, normal_rad=line.ang, offset_m=line.off,
                                     along_m=(float(along.min()), float(along.max())),
                                     frames=line.frames,
                                     images=int(np.unique(line.props[line.props[:, 1] == s,
                                                                     0]).size)))
    return walls


def _lines(props: NDArray, xy: NDArray, confirmed: NDArray, poses: NDArray,
           counts: _LineCounts | None = None) -> list[_Line]:
    """The lines that ``props`` propose in at least :data:`WALL_MIN_FRAMES`
    distinct frames, best supported first, behind which at most
    :data:`WALL_MAX_CROSSING` of the ``confirmed`` rows stand (not counting
    the images each explains).

    Each line is the best supported of the proposals left: proposals
    binned by angle and offset (half the tolerances), each bin's
    neighbourhood (two bins each way) counted in distinct frames, the first
    of the best bins taken. Its counts (``counts``: those of ``props``,
    default counted here) are updated as proposals are taken instead of
    counted again (the same lines)."""
    found = []
    if counts is None:
        counts = _LineIndex(props).counts(np.arange(len(props)))
    alive = np.ones(len(props), dtype=bool)
    while alive.any():
        count, mask_all = counts.best()
        if count < WALL_MIN_FRAMES:
            break
        left = props[alive]
        mask = mask_all[alive]
        ang = float(np.angle(np.mean(np.exp(1j * left[mask, 2]))))
        off = float(np.median(left[mask, 3]))
        near = _near(left, ang, off)
        explained = np.zeros(len(xy), dtype=bool)
        explained[left[near, 0].astype(np.int64)] = True
        n = np.array([np.cos(ang), np.sin(ang)])
        crossing = confirmed & ~explained & (xy @ n > off)
        if crossing.sum() <= WALL_MAX_CROSSING * confirmed.sum():
            nodes = np.unique(left[near, 1]).astype(np.int64)
            found.append(_Line(ang, off, left[near], count, explained,
                               off - float(np.max(poses[nodes, :2] @ n))))
        taken = np.flatnonzero(alive)[_near(left, ang, off, 2.0) | mask]
        alive[taken] = False
        counts.take(taken)
    return found


class _LineIndex:
    """The bins of the line search (:func:`_lines`) of every proposal, for counting any
    subset's lines (:meth:`counts`): each proposal's (angle, offset) bin and
    (bin, frame) pair, and the 25 (bin, frame) keys each pair lends to the
    bins of its neighbourhood (two bins each way). The offsets' bins are
    counted from the lowest of all the proposals, so the bins' order (angle,
    then offset) is that of the bins counted from the subset alone."""

    def __init__(self, props: NDArray):
        self.n_a = n_a = int(np.ceil(2 * np.pi / _BIN_RAD))
        self.a = a = np.floor(props[:, 2] / _BIN_RAD).astype(np.int64) % n_a
        o = np.floor(props[:, 3] / _BIN_M).astype(np.int64)
        self.o = o = o - (o.min() - 2) if o.size else o
        self.n_o = n_o = int(o.max()) + 3 if o.size else 1
        frames, f = np.unique(props[:, 5], return_inverse=True)
        n_f = max(frames.size, 1)
        pair, pair_of = np.unique((a * n_o + o) * n_f + f.ravel(), return_inverse=True)
        self.pair_of = pair_of.ravel()
        self.n_pairs = pair.size
        ba, rest = np.divmod(pair, n_o * n_f)
        bo, bf = np.divmod(rest, n_f)
        keys = np.stack([(((ba + da) % n_a) * n_o + bo + do) * n_f + bf
                         for da in range(-2, 3) for do in range(-2, 3)], axis=1)
        lent, key_of = np.unique(keys.ravel(), return_inverse=True)
        self.key_of = key_of.reshape(keys.shape)
        self.n_keys = lent.size
        self.bins, bin_of = np.unique(lent // n_f, return_inverse=True)
        self.bin_of = bin_of.ravel()

    def counts(self, rows: NDArray) -> _LineCounts:
        """The counts of the proposals ``rows`` (indices, in order)."""
        return _LineCounts(self, rows)


class _LineCounts:
    """The counts of the line search for some proposals (``rows`` of a
    :class:`_LineIndex`) not yet taken: each bin's distinct frames within two
    bins each way, i.e. the (bin, frame) keys lent to it by at least one
    proposal left. Taking proposals (:meth:`take`) lowers those numbers, so
    :meth:`best` is the best line of the proposals left without counting
    them all again."""

    def __init__(self, index: _LineIndex, rows: NDArray):
        self.index = index
        self.a, self.o = index.a[rows], index.o[rows]
        self.pair_of = index.pair_of[rows]
        self.props_left = np.bincount(self.pair_of, minlength=index.n_pairs)
        self.pairs_left = np.bincount(index.key_of[self.props_left > 0].ravel(),
                                      minlength=index.n_keys)
        self.count = np.bincount(index.bin_of[self.pairs_left > 0], minlength=index.bins.size)

    def best(self) -> tuple[int, NDArray]:
        """(distinct frames, mask of the proposals of ``rows``) of the best
        line of those left (a bin without proposals left counts 0, and the
        first of the best bins is taken)."""
        index = self.index
        best = int(np.argmax(self.count))
        ca, co = divmod(int(index.bins[best]), index.n_o)
        n_a = index.n_a
        da = np.abs((self.a - ca + n_a // 2) % n_a - n_a // 2)
        return int(self.count[best]), (da <= 2) & (np.abs(self.o - co) <= 2)

    def take(self, taken: NDArray) -> None:
        """The proposals ``taken`` (positions in ``rows``, each once) are no
        longer counted."""
        if not taken.size:
            return
        index = self.index
        pairs = self.pair_of[taken]
        np.subtract.at(self.props_left, pairs, 1)
        gone = np.zeros(index.n_pairs, dtype=bool)
        gone[pairs[self.props_left[pairs] == 0]] = True
        if not gone.any():
            return
        keys = index.key_of[gone].ravel()
        np.subtract.at(self.pairs_left, keys, 1)
        empty = np.zeros(index.n_keys, dtype=bool)
        empty[keys[self.pairs_left[keys] == 0]] = True
        np.subtract.at(self.count, index.bin_of[empty], 1)


@dataclass(frozen=True, slots=True)
class _Line:
    """A line proposed in ``frames`` distinct frames: its proposals, the rows
    it explains, and its distance from the nearest node that proposed it."""

    ang: float
    off: float
    props: NDArray
    frames: int
    images: NDArray
    dist: float


def _one_per_image(found: list[_Line]) -> list[_Line]:
    """The lines without those whose images (half or more) another line
    explains better: each image proposes one line per image kind, and the
    kind the data support (more frames; on a tie the farther line, which
    flags less) is the wall."""
    return [a for a in found
            if not any(np.sum(a.images & b.images) >= 0.5 * a.images.sum()
                       and (b.frames, b.dist) > (a.frames, a.dist) for b in found if b is not a)]


def beyond_learned_walls(state: NDArray, ok: NDArray, seen: NDArray, poses: NDArray,
                         walls: list[LearnedWall]) -> tuple[NDArray, NDArray]:
    """``(flag (K,), wall (K,))``: the successful rows beyond a wall of every
    node that sees them (module doc), and the index in ``walls`` of the
    first such wall (-1: none)."""
    xy = np.asarray(state, dtype=float)[:, :2]
    k, n_nodes = seen.shape
    behind = np.zeros((k, n_nodes), dtype=bool)
    first = np.full((k, n_nodes), -1, dtype=np.int64)
    for i, w in enumerate(walls):
        n, node = w.normal, poses[w.node, :2]
        depth = xy @ n - w.offset_m
        cross = wall_crossing(node, xy, n, np.full(k, w.offset_m))
        hit = ((depth > WALL_MARGIN_M) & (cross >= w.along_m[0] - WALL_EXTENT_M)
               & (cross <= w.along_m[1] + WALL_EXTENT_M))
        first[hit & ~behind[:, w.node], w.node] = i
        behind[:, w.node] |= hit
    flag = ok & seen.any(axis=1) & np.all(behind | ~seen, axis=1)
    wall = np.where(flag, np.max(np.where(seen, first, -1), axis=1), -1)
    return flag, wall
