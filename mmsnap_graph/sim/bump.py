"""A recording in which one radar is bumped (moved) part-way through, for the
decalibration monitor (:mod:`mmsnap_graph.calibration.monitor.decalibration`, docs/CALIBRATION.md,
"Noticing a moved radar").

:func:`simulate_bumped_recording` simulates the centroid level twice with the
same target trajectory and the same random streams: once with the original
node poses and once with the bumped node's new pose. The bumped node's
centroids are the first simulation's before the bump frame and the second's
from it on; every other node is unchanged (its centroids are identical in both
simulations, since each node's noise comes from its own seeded stream). The
truth keeps the original poses; the metadata says which node moved, when, and
to which pose.
"""

from __future__ import annotations

import dataclasses
from typing import Mapping

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..data.recording import Detections, Recording
from ..errors import ValidationError
from .._validation import as_float_array, check_finite
from .networks import network_poses
from .options import SimulationOptions
from .simulator import simulate_recording, simulate_targets

__all__ = ["BUMP_METADATA_KEYS", "simulate_bumped_recording", "bumped_pose"]

#: Metadata written by :func:`simulate_bumped_recording`.
BUMP_METADATA_KEYS = ("bump_node", "bump_frame", "bump_time_s", "bumped_x_m", "bumped_y_m",
                      "bumped_phi_rad")


def bumped_pose(pose: ArrayLike, bump: ArrayLike) -> NDArray:
    """``pose + bump``: the bump ``(dx_m, dy_m, dphi_rad)`` is in the global
    frame (a shift of the node's position and a turn about its own centre)."""
    return np.asarray(pose, dtype=float) + np.asarray(bump, dtype=float)


def _splice(before: Detections, after: Detections, frame: int) -> Detections:
    """Rows of ``before`` with ``frame < frame`` then rows of ``after`` from it."""
    a = before.select(before.frame < frame)
    b = after.select(after.frame >= frame)
    cat = lambda x, y: None if x is None or y is None else np.concatenate([x, y])  # noqa: E731
    return Detections(frame=np.concatenate([a.frame, b.frame]),
                      range_m=np.concatenate([a.range_m, b.range_m]),
                      omega_rad=np.concatenate([a.omega_rad, b.omega_rad]),
                      doppler_mps=np.concatenate([a.doppler_mps, b.doppler_mps]),
                      snr_db=cat(a.snr_db, b.snr_db), target_id=cat(a.target_id, b.target_id))


def _check_bump(poses: Mapping[str, NDArray], node: str, bump, bump_time_s, n_frames,
                frame_period_s) -> tuple[NDArray, int]:
    if node not in poses:
        raise ValidationError(f"node={node!r} must be one of the network's nodes {list(poses)}")
    b = check_finite(as_float_array(bump, "bump"), "bump")
    if b.shape != (3,):
        raise ValidationError(f"bump must be (dx_m, dy_m, dphi_rad), got shape {b.shape}")
    t = float(bump_time_s)
    frame = int(np.ceil(t / frame_period_s - 1e-9))
    if not (np.isfinite(t) and 0 < frame < n_frames):
        raise ValidationError(f"bump_time_s={bump_time_s!r} must fall inside the recording "
                              f"(0, {n_frames * frame_period_s:g}) s")
    return b, frame


def simulate_bumped_recording(
    network: str | Mapping[str, ArrayLike] = "C",
    trajectory: str | ArrayLike = "random",
    *,
    node: str = "S2",
    bump: ArrayLike = (0.1, 0.0, 0.0),
    bump_time_s: float = 60.0,
    n_frames: int = 800,
    frame_period_s: float = 0.15,
    seed: int = 0,
    known_poses: bool = True,
    **options,
) -> Recording:
    """A centroid-level recording in which ``node`` moves by ``bump`` at ``bump_time_s``.

    network, trajectory, n_frames, frame_period_s, seed, known_poses and
    ``options`` (fields of :class:`~mmsnap_graph.sim.SimulationOptions`,
    e.g. ``centroid_noise``, ``n_targets``, ``physics``) are passed to
    :func:`~mmsnap_graph.sim.simulate_recording` (level ``"centroids"``).
    bump : ``(dx_m, dy_m, dphi_rad)`` added to the node's pose (global frame).
    bump_time_s : the node has its new pose from the first frame at or after
        this time (frame ``ceil(bump_time_s / frame_period_s)``).
    Returns the recording; ``truth.node_poses`` and (with ``known_poses``) the
    nodes' ``pose`` are the original poses; the metadata holds
    :data:`BUMP_METADATA_KEYS`.
    """
    if "levels" in options:
        raise ValidationError("simulate_bumped_recording simulates the centroid level only; "
                              "do not pass levels")
    poses = network_poses(network)
    b, frame = _check_bump(poses, node, bump, bump_time_s, n_frames, frame_period_s)
    opt = SimulationOptions(frame_period_s=frame_period_s, known_poses=known_poses, **options)
    states = simulate_targets(network, trajectory, n_targets=opt.n_targets, n_frames=n_frames,
                              frame_period_s=frame_period_s, seed=seed,
                              walk=opt.trajectory_options)
    opt = dataclasses.replace(opt, n_targets=1, trajectory_options=None)
    common = dict(levels=("centroids",), n_frames=n_frames, seed=seed)
    before = simulate_recording(poses, states, opt, **common)
    moved = dict(poses)
    moved[node] = bumped_pose(poses[node], b)
    after = simulate_recording(moved, states, opt, **common)
    spliced = _splice(before.nodes[node].centroids, after.nodes[node].centroids, frame)
    rec = before.with_node(dataclasses.replace(before.nodes[node], centroids=spliced))
    meta = dict(before.metadata)
    if isinstance(network, str):
        meta["network"] = network
    if isinstance(trajectory, str):
        meta["trajectory"] = trajectory
    meta.update(bump_node=node, bump_frame=frame, bump_time_s=frame * frame_period_s,
                bumped_x_m=float(moved[node][0]), bumped_y_m=float(moved[node][1]),
                bumped_phi_rad=float(moved[node][2]))
    return dataclasses.replace(rec, metadata=meta)
