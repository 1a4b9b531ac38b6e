"""Stand-ins for real TI data, made from the simulator (issue 14), and the
script that writes the small samples in data/ti/:

    python tests/ti_samples.py      # rewrites data/ti/*.bin and *.csv

Each radar's simulated 2D point cloud is lifted into 3D: every point gets a
height above the floor, then it is expressed in the frame of a sensor mounted
at ``height_m`` and tilted down by ``tilt_rad``, with the 3D radial speed of a
horizontally moving scatterer. Projecting back (factors.projection) must give
the simulated 2D points again.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

from factors.models import detection_to_local  # noqa: E402
from factors.projection import level_to_sensor, sensor_to_room  # noqa: E402
from mmsnap_graph.sim import simulate_recording  # noqa: E402
from ti_encode import encode_oob_frame  # noqa: E402

DATA = ROOT / "data" / "ti"
#: node -> (mounting height m, down tilt rad) of the samples.
MOUNTS = {"S1": (0.8, np.deg2rad(5.0)), "S2": (1.2, np.deg2rad(15.0))}
FRAME_PERIOD_S = 0.05


def simulated(n_frames=20, seed=1):
    """A simulated recording (point clouds) at 20 fps."""
    return simulate_recording("C", "straight", levels=["point_cloud"], n_frames=n_frames,
                              frame_period_s=FRAME_PERIOD_S, seed=seed)


def lift(det, height_m, tilt_rad, seed):
    """2D detections -> sensor-frame ``(xyz (K, 3), doppler_3d (K,))``."""
    rng = np.random.default_rng(seed)
    local = detection_to_local(det.range_m, det.omega_rad)
    z_floor = rng.uniform(0.3, 1.7, len(det))
    level = np.column_stack([local, z_floor - height_m])
    xyz = level_to_sensor(level, tilt_rad)
    r3 = np.linalg.norm(xyz, axis=1)
    return xyz, det.doppler_mps * det.range_m / r3


def write_uart_log(path, det, height_m, tilt_rad, seed, first_frame=1):
    xyz, dop = lift(det, height_m, tilt_rad, seed)
    frames = np.unique(det.frame)
    packets = []
    for f in range(int(frames.min()), int(frames.max()) + 1):
        rows = det.frame == f
        packets.append(encode_oob_frame(f + first_frame, xyz[rows], dop[rows], det.snr_db[rows],
                                        np.full(rows.sum(), 45.0)))
    Path(path).write_bytes(b"".join(packets))


def table_rows(rec, *, room: bool, seed=0):
    """Rows of a CSV with every node (node column); sensor or room frame."""
    import pandas as pd
    parts = []
    for k, (name, node) in enumerate(rec.nodes.items()):
        height, tilt = MOUNTS[name]
        det = node.point_cloud
        xyz, dop = lift(det, height, tilt, seed + k)
        if room:
            xyz = sensor_to_room(xyz, rec.truth.node_poses[name], height, tilt)
        parts.append(pd.DataFrame({"node": name, "frame": det.frame,
                                   "time_s": 1700000000.0 + det.frame * FRAME_PERIOD_S,
                                   "x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2],
                                   "doppler": dop, "snr": det.snr_db}))
    return pd.concat(parts, ignore_index=True)


def main(out_dir: Path = DATA) -> None:
    out_dir = Path(out_dir)
    rec = simulated()
    height, tilt = MOUNTS["S1"]
    write_uart_log(out_dir / "oob_uart_S1.bin", rec.nodes["S1"].point_cloud, height, tilt,
                   seed=0)
    table_rows(rec, room=False).to_csv(out_dir / "points_sensor_frame.csv", index=False,
                                       float_format="%.6f")
    table_rows(rec, room=True).to_csv(out_dir / "points_room_frame.csv", index=False,
                                      float_format="%.6f")


if __name__ == "__main__":
    main()
