"""The joint calibration graph with several people.

:func:`~mmsnap_graph.calibration.joint.solve.joint_calibration` takes one detection
of the common target per node per frame. With several people walking, each
node sees several centroids per frame, and which centroid of one node is
which of another's is not known. This module associates them across nodes
*with the calibration in progress* (the pose graph's poses and lags) and
hands the joint graph one detection per node per (frame, target):

1. **Map** every centroid of every node to the global frame with
   ``factors.models.detection_to_global`` and the node's pose, on the
   reference's frame clock (node frame ``k + lag`` is reference frame
   ``k``), with a covariance: the detection's
   (``factors.models.detection_covariance_global`` of the association
   noise) plus the pose's, propagated through ``p = t + R(phi) p_local``
   and inflated (``pose_inflation``; pose-graph covariances are optimistic:
   correlated residuals), plus a floor (``floor_m``).
2. **Group** each frame's centroids: complete-linkage agglomeration on the
   Mahalanobis distance of every pair of centroids of *different* nodes;
   two groups merge when no node is in both and every cross pair is within
   the chi-square(2) ``gate_probability`` gate. A group seen by at least
   two nodes is one target at that frame.
3. **Link** the groups from frame to frame into target tracks: a group's
   velocity is fitted to its members' Dopplers (each node measures the
   velocity along its line of sight), a track's last centre is carried
   forward by it, and a group within ``link_gate_m + velocity_error_mps *
   dt`` continues the track (a gap of at most ``max_gap_s``).
   A link that is ambiguous (a second group or a second track inside the
   gate: two people passing close) is not made: the track ends and a new
   one starts, so a track never jumps from one person to another.
4. **Relabel** the frames: each target track gets its own block of
   *virtual* frame numbers, ``offset_j + (k - k_first_j)``, blocks
   ``max_motion_gap_frames + 1`` frames apart, so the joint graph's motion
   factors link the states of one track only (never two people) and keep
   the true time steps within a track. :func:`joint_calibration` then runs
   unchanged; :class:`TargetMapping` maps its states back to
   ``(frame, target)``.

:func:`joint_detections_multi` returns the relabelled detections (this
module imports neither :mod:`~mmsnap_graph.calibration.network` nor GTSAM-heavy steps, so that
:mod:`~mmsnap_graph.calibration.network` can call it); :func:`~mmsnap_graph.calibration.joint.multi_refine.refine_multi`
runs the joint graph on them from a pose-graph result.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import linear_sum_assignment

from factors.models import detection_covariance_global, detection_to_global, detection_to_local

from ...data.noise import MeasurementNoise
from ...data.recording import Detections, Recording
from ...errors import CalibrationError, ValidationError
from ..._validation import check_count, check_positive, check_probability, chi2_gate
from .solve import JointCalibration

__all__ = ["ASSOCIATION_NOISE", "AssociationOptions", "TargetMapping", "TargetAssociation",
           "associate_targets",
           "joint_detections_multi", "target_states"]

#: Centroid noise assumed by the association gates when none is given: the
#: per-node EKF's default measurement sigmas (range 5 cm, spatial frequency
#: 0.1 rad, Doppler 0.2 m/s), which cover the chain's torso centroids.
ASSOCIATION_NOISE = MeasurementNoise(range_m=0.05, omega_rad=0.1, doppler_mps=0.2)


@dataclass(frozen=True, kw_only=True, slots=True)
class TargetMapping:
    """Virtual frames of the joint graph -> ``(frame, target)``.

    virtual_frame, frame, target : (V,) int, sorted by virtual frame; frame
    on the reference node's clock. n_targets : number of target tracks.
    """

    virtual_frame: NDArray
    frame: NDArray
    target: NDArray
    n_targets: int

    def lookup(self, virtual_frames: ArrayLike) -> tuple[NDArray, NDArray]:
        """``(frame, target)`` of each virtual frame; a virtual frame that is
        not in the mapping raises :class:`ValidationError`."""
        v = np.asarray(virtual_frames, dtype=np.int64)
        idx = np.clip(np.searchsorted(self.virtual_frame, v), 0,
                      max(self.virtual_frame.size - 1, 0))
        if self.virtual_frame.size == 0 or np.any(self.virtual_frame[idx] != v):
            raise ValidationError("virtual_frames holds frames that are not in the mapping")
        return self.frame[idx], self.target[idx]


@dataclass(frozen=True, kw_only=True, slots=True)
class TargetAssociation:
    """Result of :func:`associate_targets`.

    target : node name -> (K_n,) int, the target track of each of the node's
        centroids (``-1``: not associated: alone in its frame's group, or
        in a group seen by one node only).
    frame : node name -> (K_n,) int, each centroid's frame on the reference
        clock (its frame minus the node's lag).
    n_targets : number of target tracks.
    n_groups : groups seen by at least two nodes (targets x frames).
    n_breaks : links not made because they were ambiguous.
    """

    target: Mapping[str, NDArray]
    frame: Mapping[str, NDArray]
    n_targets: int
    n_groups: int
    n_breaks: int


def _pose_covariance_global(p_local: NDArray, pose: NDArray, cov: NDArray) -> NDArray:
    """(K, 2, 2) covariance of ``t + R(phi) p_local`` from the pose's
    body-tangent covariance (3, 3): ``d p / d xi = R [I, J p_local]``."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    rot = np.array([[c, -s], [s, c]])
    jac = np.zeros((p_local.shape[0], 2, 3))
    jac[:, 0, 0] = jac[:, 1, 1] = 1.0
    jac[:, 0, 2] = -p_local[:, 1]
    jac[:, 1, 2] = p_local[:, 0]
    jac = rot @ jac
    return jac @ cov @ np.swapaxes(jac, -1, -2)


def _global_rows(recording, names, poses, covariances, lags, noise, pose_inflation, floor_m):
    """Every centroid of every node: reference-clock frame, node index, row
    in the node's centroids, global point (K, 2), its covariance (K, 2, 2),
    the global unit vector from the node to it (K, 2) and its Doppler (K,)."""
    parts = []
    for i, n in enumerate(names):
        det = recording.nodes[n].centroids
        if det is None or len(det) == 0:
            continue
        pose = np.asarray(poses[n], dtype=float)
        pts = detection_to_global(det.range_m, det.omega_rad, pose)
        cov = detection_covariance_global(det.range_m, det.omega_rad, pose, noise.range_m,
                                          noise.omega_rad)
        pcov = covariances.get(n) if covariances is not None else None
        if pcov is not None and np.all(np.isfinite(pcov)):
            cov = cov + pose_inflation**2 * _pose_covariance_global(
                detection_to_local(det.range_m, det.omega_rad), pose, np.asarray(pcov, float))
        cov = cov + floor_m**2 * np.eye(2)
        radial = pts - pose[:2]
        radial /= np.maximum(np.linalg.norm(radial, axis=1, keepdims=True), 1e-9)
        parts.append((det.frame - int(lags.get(n, 0)), np.full(len(det), i),
                      np.arange(len(det)), pts, cov, radial, det.doppler_mps))
    if not parts:
        raise CalibrationError("no node has centroids to associate")
    cat = [np.concatenate([p[j] for p in parts]) for j in range(7)]
    order = np.argsort(cat[0], kind="stable")
    return tuple(a[order] for a in cat)


def _pair_d2(pts: NDArray, cov: NDArray) -> NDArray:
    """(m, m) Mahalanobis distances ``d^T (C_i + C_j)^-1 d`` of 2-vectors."""
    d = pts[:, None, :] - pts[None, :, :]
    s = cov[:, None] + cov[None, :]
    det = s[..., 0, 0] * s[..., 1, 1] - s[..., 0, 1] * s[..., 1, 0]
    q = (s[..., 1, 1] * d[..., 0] ** 2 - 2 * s[..., 0, 1] * d[..., 0] * d[..., 1]
         + s[..., 0, 0] * d[..., 1] ** 2)
    return q / det


def _group_frame(node: NDArray, pts: NDArray, cov: NDArray, gate_d2: float) -> NDArray:
    """(m,) group labels of one frame's centroids (module doc, step 2)."""
    m = node.size
    labels = np.arange(m)
    if m == 1:
        return labels
    link = _pair_d2(pts, cov)
    link[node[:, None] == node[None, :]] = np.inf
    members = [{i} for i in range(m)]
    nodes = [{int(node[i])} for i in range(m)]
    alive = np.ones(m, bool)
    while True:
        masked = np.where(alive[:, None] & alive[None, :], link, np.inf)
        np.fill_diagonal(masked, np.inf)
        a, b = np.unravel_index(np.argmin(masked), masked.shape)
        if not masked[a, b] < gate_d2:
            break
        a, b = min(a, b), max(a, b)
        members[a] |= members[b]
        nodes[a] |= nodes[b]
        alive[b] = False
        link[a] = link[:, a] = np.maximum(link[a], link[b])  # complete linkage
        for c in np.flatnonzero(alive):
            if c != a and nodes[a] & nodes[c]:
                link[a, c] = link[c, a] = np.inf            # one centroid per node
    for g in np.flatnonzero(alive):
        labels[list(members[g])] = g
    return labels


#: Sigmas of the group velocity fit (m/s): the Dopplers' and a zero-mean
#: walking-speed prior that keeps two nearly parallel lines of sight posed.
_VELOCITY_FIT_SIGMAS = (0.2, 1.5)


def _group_velocity(radial: NDArray, doppler: NDArray) -> NDArray:
    """Velocity (2,) whose projections on the lines of sight ``radial``
    (m, 2) best fit the Dopplers (each node measures ``u . v``)."""
    s_d, s_v = _VELOCITY_FIT_SIGMAS
    a = radial.T @ radial / s_d**2 + np.eye(2) / s_v**2
    return np.linalg.solve(a, radial.T @ doppler / s_d**2)


def _groups(frame, node, pts, cov, radial, doppler, gate_d2):
    """Group every frame; returns per row its group id (global numbering),
    and per group its frame, centre (information-weighted mean), velocity
    (from the members' Dopplers) and number of nodes."""
    bounds = np.flatnonzero(np.diff(frame)) + 1
    row_group = np.empty(frame.size, np.int64)
    g_frame, g_centre, g_vel, g_nodes = [], [], [], []
    for rows in np.split(np.arange(frame.size), bounds):
        lab = _group_frame(node[rows], pts[rows], cov[rows], gate_d2)
        for g in np.unique(lab):
            sel = rows[lab == g]
            info = np.linalg.inv(cov[sel])
            centre = np.linalg.solve(info.sum(0), np.einsum("kij,kj->i", info, pts[sel]))
            row_group[sel] = len(g_frame)
            g_frame.append(int(frame[rows[0]]))
            g_centre.append(centre)
            g_vel.append(_group_velocity(radial[sel], doppler[sel]))
            g_nodes.append(sel.size)
    return (row_group, np.asarray(g_frame), np.asarray(g_centre), np.asarray(g_vel),
            np.asarray(g_nodes))


def _link(g_frame, g_centre, g_vel, usable, frame_period_s, link_gate_m, velocity_error_mps,
          ambiguity_m, max_gap):
    """Target track of each usable group (module doc, step 3); -1 for the
    others. The track's last centre is carried forward by the mean of its
    last velocity and the group's (both from Dopplers) over the time between
    them; the groups within ``link_gate_m + velocity_error_mps * dt`` of
    it are candidates, assigned by least total distance; a link is kept only
    when every other candidate of its track and of its group (but a staler
    track farther away) is at least ``ambiguity_m`` farther, else the track
    ends (its group starts a new track). Returns ``(track (G,), number of tracks, breaks)``."""
    track = np.full(g_frame.size, -1, np.int64)
    last_frame: list[int] = []
    last_pos: list[NDArray] = []
    last_vel: list[NDArray] = []
    open_tracks: list[int] = []
    n_breaks = 0
    idx = np.flatnonzero(usable)
    bounds = np.flatnonzero(np.diff(g_frame[idx])) + 1
    for groups in np.split(idx, bounds) if idx.size else []:
        f = int(g_frame[groups[0]])
        open_tracks = [t for t in open_tracks if f - last_frame[t] <= max_gap]
        assigned: dict[int, int] = {}
        if open_tracks:
            dt = np.array([f - last_frame[t] for t in open_tracks]) * frame_period_s
            pos = np.array([last_pos[t] for t in open_tracks])
            vel = np.array([last_vel[t] for t in open_tracks])
            pred = (pos[:, None, :] + 0.5 * (vel[:, None, :] + g_vel[groups][None, :, :])
                    * dt[:, None, None])
            dist = np.linalg.norm(pred - g_centre[groups][None, :, :], axis=-1)
            dist[dist > (link_gate_m + velocity_error_mps * dt)[:, None]] = np.inf
            rows, cols = linear_sum_assignment(np.where(np.isfinite(dist), dist, 1e9))
            ended = set()
            for r, c in zip(rows, cols):
                if not np.isfinite(dist[r, c]):
                    continue
                # Rivals: other groups in this track's gate, other tracks
                # wanting this group (a staler track farther away is not one:
                # a walker's track restarted after a miss leaves the old one
                # open until max_gap).
                rival_rows = np.delete(np.arange(dist.shape[0]), r)
                stale = (dt[rival_rows] > dt[r]) & (dist[rival_rows, c] > dist[r, c])
                others = np.concatenate([np.delete(dist[r], c), dist[rival_rows[~stale], c]])
                if others.size and others.min() < dist[r, c] + ambiguity_m:
                    ended.add(open_tracks[r])      # two people close: do not guess
                    continue
                assigned[int(groups[c])] = open_tracks[r]
            n_breaks += len(ended)
            open_tracks = [t for t in open_tracks if t not in ended]
        for g in groups:
            t = assigned.get(int(g))
            if t is None:
                t = len(last_frame)
                last_frame.append(f)
                last_pos.append(g_centre[g])
                last_vel.append(g_vel[g])
                open_tracks.append(t)
            track[g] = t
            last_frame[t], last_pos[t], last_vel[t] = f, g_centre[g], g_vel[g]
    return track, len(last_frame), n_breaks


@dataclass(frozen=True, kw_only=True, slots=True)
class AssociationOptions:
    """How :func:`associate_targets` groups and links the centroids.

    noise : centroid noise of the gates (range and spatial frequency); None:
        :data:`ASSOCIATION_NOISE` (and, in the rounds of
        :func:`~mmsnap_graph.calibration.joint.multi_refine.refine_associated`,
        the noise learned from the previous round).
    gate_probability : chi-square(2) gate of two centroids being one target.
    pose_inflation, floor_m : the pose covariance is scaled by
        ``pose_inflation ** 2`` and ``floor_m ** 2 I`` added to every
        centroid's covariance.
    link_gate_m, velocity_error_mps, max_gap_s : a group continues a track
        seen at most ``max_gap_s`` before when it lies within ``link_gate_m +
        velocity_error_mps * dt`` of the track's last centre carried forward
        by the Doppler velocities (module doc, step 3).
    ambiguity_m : a link is not made when another candidate is less than
        this farther (two people close together): the track ends there.
    """

    noise: MeasurementNoise | None = None
    gate_probability: float = 0.999
    pose_inflation: float = 3.0
    floor_m: float = 0.1
    link_gate_m: float = 0.3
    velocity_error_mps: float = 1.0
    ambiguity_m: float = 0.1
    max_gap_s: float = 0.5

    def __post_init__(self) -> None:
        object.__setattr__(self, "gate_probability",
                           check_probability(self.gate_probability, "gate_probability"))
        for name, strict in (("pose_inflation", False), ("floor_m", True), ("link_gate_m", True),
                             ("velocity_error_mps", True), ("ambiguity_m", False),
                             ("max_gap_s", True)):
            value = check_positive(getattr(self, name), name, strict=strict)
            object.__setattr__(self, name, float(value))
        if self.noise is not None and not isinstance(self.noise, MeasurementNoise):
            raise ValidationError(f"noise must be a MeasurementNoise or None, got {self.noise!r}")


def associate_targets(
    recording: Recording,
    names: Sequence[str],
    poses: Mapping[str, ArrayLike],
    lag_frames: Mapping[str, int],
    *,
    covariances: Mapping[str, ArrayLike] | None = None,
    options: AssociationOptions | None = None,
) -> TargetAssociation:
    """Assign every node's centroids to common target tracks (module doc,
    steps 1-3).

    names : the nodes to associate (each with a pose in ``poses``).
    poses, lag_frames, covariances : the calibration in progress (e.g. a
        pose graph's :class:`~mmsnap_graph.data.calibration.RecordingCalibration`:
        ``poses``, ``lag_frames`` and ``covariances``; no covariances: the
        floor only).
    options : the gates (:class:`AssociationOptions`; None: its defaults).
    """
    o = AssociationOptions() if options is None else options
    if not isinstance(o, AssociationOptions):
        raise ValidationError(f"options must be an AssociationOptions, got {o!r}")
    noise = ASSOCIATION_NOISE if o.noise is None else o.noise
    names = [str(n) for n in names]
    missing = [n for n in names if n not in poses or n not in recording.nodes]
    if missing:
        raise ValidationError(f"nodes {missing} have no pose or are not in the recording")
    frame, node, row, pts, cov, radial, doppler = _global_rows(recording, names, poses, covariances, lag_frames,
                                              noise, o.pose_inflation, o.floor_m)
    row_group, g_frame, g_centre, g_vel, g_size = _groups(
        frame, node, pts, cov, radial, doppler, chi2_gate(o.gate_probability, 2))
    max_gap = max(1, int(np.ceil(o.max_gap_s / recording.frame_period_s - 1e-9)))
    g_track, n_tracks, n_breaks = _link(g_frame, g_centre, g_vel, g_size >= 2,
                                        recording.frame_period_s, o.link_gate_m,
                                        o.velocity_error_mps, o.ambiguity_m, max_gap)
    target, frames = {}, {}
    for i, n in enumerate(names):
        det = recording.nodes[n].centroids
        k = 0 if det is None else len(det)
        t = np.full(k, -1, np.int64)
        sel = node == i
        t[row[sel]] = g_track[row_group[sel]]
        target[n] = t
        frames[n] = (np.zeros(0, np.int64) if det is None
                     else det.frame - int(lag_frames.get(n, 0)))
    return TargetAssociation(target=target, frame=frames, n_targets=int(n_tracks),
                             n_groups=int(np.sum(g_size >= 2)), n_breaks=int(n_breaks))


def _virtual_frames(assoc: TargetAssociation, gap: int) -> TargetMapping:
    """Each target track's block of virtual frames (module doc, step 4)."""
    fr = np.concatenate([assoc.frame[n][assoc.target[n] >= 0] for n in assoc.target])
    tg = np.concatenate([assoc.target[n][assoc.target[n] >= 0] for n in assoc.target])
    pairs = np.unique(np.stack([tg, fr], axis=1), axis=0)  # sorted by target, then frame
    targets, first = np.unique(pairs[:, 0], return_index=True)
    last = np.append(first[1:], pairs.shape[0]) - 1
    start, span = pairs[first, 1], pairs[last, 1] - pairs[first, 1]
    offset = np.concatenate([[0], np.cumsum(span + gap)[:-1]])
    which = np.searchsorted(targets, pairs[:, 0])
    virtual = offset[which] + pairs[:, 1] - start[which]
    return TargetMapping(virtual_frame=virtual.astype(np.int64), frame=pairs[:, 1].copy(),
                         target=pairs[:, 0].copy(), n_targets=int(targets.size))


def joint_detections_multi(
    recording: Recording,
    names: Sequence[str],
    poses: Mapping[str, ArrayLike],
    lag_frames: Mapping[str, int],
    *,
    covariances: Mapping[str, ArrayLike] | None = None,
    max_motion_gap_frames: int = 3,
    association: AssociationOptions | None = None,
) -> tuple[dict[str, Detections] | None, TargetMapping | None, TargetAssociation]:
    """Each node's associated centroids for :func:`joint_calibration`, one
    row per (virtual frame = target x frame), module doc.

    association : the gates of :func:`associate_targets`.
    max_motion_gap_frames : the joint graph's (target blocks are one frame
        further apart, so that no motion factor joins two targets).
    Returns ``(detections, mapping, association)``, detections in the order
    of ``names`` (the first, the joint graph's reference, first); detections
    and mapping are None when fewer than two nodes, or not the first node,
    have an associated centroid. ``target_id`` of the detections is the
    target track.
    """
    check_count(max_motion_gap_frames, "max_motion_gap_frames")
    assoc = associate_targets(recording, names, poses, lag_frames, covariances=covariances,
                              options=association)
    first = str(names[0])
    if (sum(bool(np.any(t >= 0)) for t in assoc.target.values()) < 2
            or not np.any(assoc.target[first] >= 0)):
        return None, None, assoc
    mapping = _virtual_frames(assoc, int(max_motion_gap_frames) + 1)
    # (target, frame) keys by the frame's rank, not its number: frames at both
    # ends of int64 have a span (np.ptp) that wraps and keys that overflow
    known = np.unique(mapping.frame)
    width = known.size
    key = mapping.target * width + np.searchsorted(known, mapping.frame)  # sorted like mapping
    out = {}
    for n in assoc.target:
        used = assoc.target[n] >= 0
        if not used.any():
            continue
        tg, fr = assoc.target[n][used], assoc.frame[n][used]
        idx = np.searchsorted(key, tg * width + np.searchsorted(known, fr))
        det = recording.nodes[n].centroids.select(np.flatnonzero(used))
        out[n] = dataclasses.replace(det, frame=mapping.virtual_frame[idx], target_id=tg)
    return out, mapping, assoc


def target_states(joint: JointCalibration, mapping: TargetMapping
                  ) -> tuple[NDArray, NDArray, NDArray]:
    """The joint graph's states as ``(frame (F,), target (F,), states (F, 4))``
    (global), from its virtual frames."""
    frame, target = mapping.lookup(joint.frames)
    return frame, target, np.asarray(joint.states)
