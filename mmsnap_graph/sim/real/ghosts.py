"""Ghost centroids for robustness tests (docs/SIMULATOR.md, "Ghost generators").

:func:`ghost_centroids` corrupts a fraction of a recording's centroids, per
node, in one of four ways real radars do:

- ``"near_range"``: the centroid replaced by one whose range is within
  +-3 m of the true one (uniform), angle uniform over the field of view and
  Doppler uniform in +-3 m/s (a clutter or limb cluster picked instead of
  the body, at a plausible distance);
- ``"uniform"``: the centroid replaced by one uniform in the field of view
  (range 0.5-10 m, angle +-60 deg, Doppler +-3 m/s);
- ``"mirror"``: an extra row, the mirror image of the centroid through a
  wall of the room (a multipath ghost, with the image's Doppler);
- ``"split"``: the centroid replaced by two, 0.3-0.6 m apart (one body seen
  as two clusters).

Corrupted and added rows have ``target_id`` -1.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from numpy.typing import ArrayLike

from factors.models import global_to_local, local_to_global, measurement_model, wrap_angle

from ...data.recording import Detections, Recording
from ...errors import ValidationError
from .physics import mirror_through_walls

__all__ = ["GHOST_KINDS", "ghost_centroids"]

GHOST_KINDS = ("near_range", "uniform", "mirror", "split")
_FOV = np.pi / 3


def _local_xy(c: Detections):
    theta = np.arcsin(np.clip(c.omega_rad / np.pi, -1, 1))
    return np.stack([c.range_m * np.sin(theta), c.range_m * np.cos(theta)], axis=1)


def _from_local(xy, frame, doppler, tid):
    r = np.hypot(xy[:, 0], xy[:, 1])
    omega = np.pi * xy[:, 0] / np.maximum(r, 1e-9)
    return frame, r, wrap_angle(omega), doppler, tid


def _replace(c: Detections, g, kind: str, rng) -> tuple:
    r, w, v = c.range_m.copy(), c.omega_rad.copy(), c.doppler_mps.copy()
    k = int(g.sum())
    if kind == "near_range":
        r[g] = np.maximum(r[g] + rng.uniform(-3.0, 3.0, k), 0.3)
    else:
        r[g] = rng.uniform(0.5, 10.0, k)
    w[g] = np.pi * np.sin(rng.uniform(-_FOV, _FOV, k))
    v[g] = rng.uniform(-3.0, 3.0, k)
    return c.frame, r, w, v, np.where(g, -1, c.target_id)


def _split(c: Detections, g, rng) -> tuple:
    xy = _local_xy(c)
    k = int(g.sum())
    ang = rng.uniform(0, 2 * np.pi, k)
    half = rng.uniform(0.3, 0.6, k)[:, None] / 2 * np.stack([np.cos(ang), np.sin(ang)], axis=1)
    keep = ~g
    f = np.concatenate([c.frame[keep], c.frame[g], c.frame[g]])
    pts = np.concatenate([xy[keep], xy[g] + half, xy[g] - half])
    dop = np.concatenate([c.doppler_mps[keep], c.doppler_mps[g], c.doppler_mps[g]])
    tid = np.concatenate([c.target_id[keep], np.full(2 * k, -1)])
    return _from_local(pts, f, dop, tid)


def _mirror(c: Detections, g, pose, room, truth_vel, rng) -> tuple:
    xy_g = local_to_global(_local_xy(c)[g], pose)
    ims, vel = mirror_through_walls(xy_g, truth_vel[g], room)           # (4, K, 2)
    loc = global_to_local(ims, pose)
    theta = np.arctan2(loc[..., 0], loc[..., 1])
    seen = np.abs(theta) <= _FOV
    score = np.where(seen, rng.random(seen.shape), -1.0)
    wall = np.argmax(score, axis=0)
    idx = np.arange(xy_g.shape[0])
    ok = seen[wall, idx]
    img, img_v = ims[wall, idx][ok], vel[wall, idx][ok]
    h, _ = measurement_model(np.concatenate([img, img_v], axis=1), pose)
    f = np.concatenate([c.frame, c.frame[g][ok]])
    r = np.concatenate([c.range_m, h[:, 0]])
    w = np.concatenate([c.omega_rad, wrap_angle(h[:, 1])])
    v = np.concatenate([c.doppler_mps, h[:, 2]])
    tid = np.concatenate([c.target_id, np.full(int(ok.sum()), -1)])
    return f, r, w, v, tid


def ghost_centroids(recording: Recording, kind: str, fraction: float, *, seed: int = 0,
                    room: ArrayLike | None = None) -> Recording:
    """``recording`` with a ``fraction`` of every node's centroids corrupted
    (module doc). ``room`` ``(x_min, x_max, y_min, y_max)`` (``"mirror"``;
    default: the truth's walking box 1 m wider). Needs the truth (true node
    poses; velocities for ``"mirror"``)."""
    if kind not in GHOST_KINDS:
        raise ValidationError(f"kind={kind!r} must be one of {GHOST_KINDS}")
    if not 0 <= fraction <= 1:
        raise ValidationError(f"fraction={fraction!r} must be in [0, 1]")
    if recording.truth is None:
        raise ValidationError("ghost_centroids needs the recording's truth")
    truth = recording.truth
    if room is None:
        xy = truth.state[:, :2]
        room = (xy[:, 0].min() - 1, xy[:, 0].max() + 1, xy[:, 1].min() - 1, xy[:, 1].max() + 1)
    room = np.asarray(room, dtype=float)
    rng = np.random.default_rng([int(seed), GHOST_KINDS.index(kind)])
    nodes = {}
    for name, node in recording.nodes.items():
        c = node.centroids
        if c is None:
            raise ValidationError(f"nodes[{name}] has no centroids")
        tid = np.zeros(len(c), np.int64) if c.target_id is None else c.target_id
        c = dataclasses.replace(c, target_id=tid)
        g = rng.random(len(c)) < fraction
        if kind in ("near_range", "uniform"):
            cols = _replace(c, g, kind, rng)
        elif kind == "split":
            cols = _split(c, g, rng)
        else:
            vel = np.zeros((len(c), 2))
            lookup = {(int(f), int(t)): s for f, t, s in zip(truth.frame, truth.target_id,
                                                              truth.state)}
            for i, (f, t) in enumerate(zip(c.frame, tid)):
                s = lookup.get((int(f), int(t)))
                if s is not None:
                    vel[i] = s[2:]
            cols = _mirror(c, g, truth.node_poses[name], room, vel, rng)
        f, r, w, v, t = cols
        order = np.argsort(f, kind="stable")
        snr = None
        nodes[name] = dataclasses.replace(node, centroids=Detections(
            frame=f[order], range_m=np.abs(r[order]), omega_rad=w[order], doppler_mps=v[order],
            snr_db=snr, target_id=t[order]))
    return dataclasses.replace(recording, nodes=nodes)
