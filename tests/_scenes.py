"""Small synthetic calibration scenes shared by several test modules."""

from __future__ import annotations

import numpy as np

from factors.models import measurement_model
from mmsnap_graph.data.recording import Detections, NodeData, Recording

__all__ = ["depth_scene", "small_room_image", "ROOM3"]


def depth_scene(sigmas, seed: int = 0, n: int = 60, depth: float = 0.07):
    """Three nodes seeing a target on a smooth walk, every range ``depth``
    short (a body's reflection depth), noise ``sigmas`` (range_m, omega_rad,
    doppler_mps). Returns ``(poses, states, measurements)``."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.15
    states = np.column_stack([1.5 * np.sin(0.3 * t), 3.5 + np.cos(0.4 * t),
                              0.45 * np.cos(0.3 * t), -0.4 * np.sin(0.4 * t)])
    poses = {"S1": np.zeros(3), "S2": np.array([4.0, 4.0, np.pi / 2]),
             "S3": np.array([0.5, 7.5, np.pi])}
    meas = {}
    for name, pose in poses.items():
        h, _ = measurement_model(states, pose)
        h[:, 0] -= depth
        meas[name] = h + rng.normal(0.0, sigmas, (n, 3))
    return poses, states, meas


#: A room with three radars (not the paper's): S3 faces S1 from 6 m.
ROOM3 = np.array([[0.0, 0.0, 0.0], [4.0, 0.0, np.pi / 3], [2.0, 6.0, np.pi]])


def small_room_image(n_frames=40, period_s=0.05, seed=4):
    """Centroids of a walker near (2, 3.3) that all three radars see, and a
    multipath image of him that S2 sees alone at (2.7, 7.2), beyond the wall
    behind S3: 7.6 m from S1, in its view, where the walker never goes
    (S1's own detections of him end 4.3 m away). S1's point cloud holds the
    scene it also sees: a static reflector at 9 m. Returns ``(recording,
    walker (F, 4), image (F, 4))``."""
    rng = np.random.default_rng(seed)
    t = np.arange(n_frames) * period_s
    walker = np.stack([1.7 + 0.5 * t, 3.0 + 0.2 * t, np.full_like(t, 0.5), np.full_like(t, 0.2)], 1)
    image = np.stack([2.9 - 0.2 * t, 7.2 + 0 * t, np.full_like(t, -0.2), 0 * t], 1)
    nodes = {}
    for i, pose in enumerate(ROOM3):
        rows = [walker] + ([image] if i == 1 else [])
        frame = np.concatenate([np.arange(n_frames)] * len(rows))
        h = np.concatenate([measurement_model(s, pose)[0] for s in rows])
        h += rng.normal(0, [0.02, 0.01, 0.05], h.shape)
        det = Detections(frame=frame, range_m=h[:, 0], omega_rad=h[:, 1], doppler_mps=h[:, 2])
        order = np.argsort(det.frame, kind="stable")
        det = Detections(frame=det.frame[order], range_m=det.range_m[order],
                         omega_rad=det.omega_rad[order], doppler_mps=det.doppler_mps[order])
        cloud = None
        if i == 0:
            cloud = Detections(frame=np.array([0]), range_m=np.array([9.0]),
                               omega_rad=np.array([0.3]), doppler_mps=np.array([0.0]))
        nodes[f"S{i + 1}"] = NodeData(name=f"S{i + 1}", pose=pose, centroids=det,
                                      point_cloud=cloud)
    return Recording(frame_period_s=period_s, nodes=nodes), walker, image
