"""Values shared by several test modules: the paper's networks and sigmas, a
small radar configuration, the samples folder.

Plain constants (not fixtures) because several are used at parametrize time,
where pytest fixtures cannot be; the fixtures built on them (recordings) are in
``conftest.py``. The node poses come from the library's one definition
(:data:`mmsnap_graph.sim.networks.CONFIGURATIONS`, pinned by
``test_sim_geometry``), the sigmas from the library's defaults (pinned by
``test_oneshot``); every array here is read-only so no test can change another's.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mmsnap_graph.data.noise import GaussianPrior, MeasurementNoise
from mmsnap_graph.data.radar_config import RadarConfig
from mmsnap_graph.sim import network_poses

__all__ = [
    "ROOT", "DATA", "TI_DATA", "network_array", "POSES_A", "POSES_B", "POSES_C", "POSES_BC",
    "NETWORK_BCA", "NETWORK_3", "NETWORK_3_OPEN", "PAPER_NOISE", "PAPER_PRIOR", "PAPER_SIGMAS", "TRACK_NOISE", "SMALL_RADAR",
]

#: The repository root, its samples folder ``data/`` and the TI samples ``data/ti/``.
ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "data"
TI_DATA = DATA / "ti"


def _frozen(a: np.ndarray) -> np.ndarray:
    a = np.array(a, dtype=float)
    a.setflags(write=False)
    return a


def network_array(configuration: str) -> np.ndarray:
    """(N, 3) node poses of the paper's configuration, S1 first (read-only)."""
    return _frozen(np.stack(list(network_poses(configuration).values())))


#: (2, 3) node poses of the paper's configurations A, B, C (S1 at the origin).
POSES_A = network_array("A")
POSES_B = network_array("B")
POSES_C = network_array("C")
#: (3, 3) S1 and the S2 of configurations B and C: a three-node network.
POSES_BC = _frozen(np.vstack([POSES_B, POSES_C[1:]]))
#: Four named nodes: S1 and the S2 of B, C and A (as S2, S3, S4).
NETWORK_BCA = {"S1": POSES_A[0], "S2": POSES_B[1], "S3": POSES_C[1], "S4": POSES_A[1]}

#: Three nodes facing a common area: S1 (0, 0, 0), S2 (5, 5, pi/2), S3 (0, 7, pi)
#: (the network of the calibration NEES tests and of ``three_node_recording``).
NETWORK_3 = {"S1": _frozen([0.0, 0.0, 0.0]), "S2": _frozen([5.0, 5.0, np.pi / 2]),
             "S3": _frozen([0.0, 7.0, np.pi])}

#: Three nodes around an open area: S1 (0, 0, 0), S2 (0, 7, pi), S3 (4, 0, pi/6)
#: (the network of the sparse point cloud tests and of ``point_cloud_recording_3``).
NETWORK_3_OPEN = {"S1": _frozen([0.0, 0.0, 0.0]), "S2": _frozen([0.0, 7.0, np.pi]),
                  "S3": _frozen([4.0, 0.0, np.pi / 6])}

#: The paper's measurement noise, prior and sigmas (range_m, omega_rad, doppler_mps).
PAPER_NOISE = MeasurementNoise()
PAPER_PRIOR = GaussianPrior()
PAPER_SIGMAS = _frozen(PAPER_NOISE.sigmas)
#: Track-like noise: an EKF smooths the spatial frequency well below its raw
#: sigma (0.05 rad gives ~10 cm across range at 5 m).
TRACK_NOISE = MeasurementNoise(range_m=0.035, omega_rad=0.05, doppler_mps=0.18)

#: A small radar (256 samples x 128 loops, 2 TX) for fast signal-chain tests.
SMALL_RADAR = RadarConfig(n_samples=256, n_loops=128, tx_azimuth_half_wl=(0.0, 4.0),
                          tx_elevation_half_wl=(0.0, 0.0), frame_period_s=0.1)


def csv_lines(tmp_path, lines, name="log.csv") -> Path:
    """``lines`` written as a CSV file ``name`` in ``tmp_path``."""
    path = tmp_path / name
    path.write_text("\n".join(lines) + "\n")
    return path


def replace_cell(line: str, column: int, value: str) -> str:
    """A CSV line with its ``column``-th cell replaced by ``value``."""
    cells = line.split(",")
    cells[column] = value
    return ",".join(cells)
