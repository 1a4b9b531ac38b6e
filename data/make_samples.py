"""Regenerate the sample recordings in data/ (deterministic seeds).

Run from anywhere: ``python data/make_samples.py [--out DIR]``.

- ``config_<A|B|C>_<straight|random>.h5``: two nodes, 600 frames (90 s at
  150 ms), centroids and point clouds, truth; node poses unknown (to be
  calibrated), the true poses in ``/truth/node_poses``.
- ``cubes_B_random_4frames.h5``: two nodes, 4 frames of Table I raw ADC cubes
  (int16 ADC counts, thermal noise std 4 counts, static clutter) plus the
  centroids, point clouds and truth of the same frames.

See docs/SIMULATOR.md for the models and data/README.md for the list.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from mmsnap_graph.io import write_recording
from mmsnap_graph.sim import CubeModel, simulate_recording
from mmsnap_graph.sim import CLEAN, SimulationOptions

#: (configuration, trajectory) -> seed
SEEDS = {
    ("A", "straight"): 101, ("A", "random"): 102,
    ("B", "straight"): 201, ("B", "random"): 202,
    ("C", "straight"): 301, ("C", "random"): 302,
}
CUBE_SEED = 401


def make_samples(out: Path) -> list[Path]:
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for (config, trajectory), seed in SEEDS.items():
        rec = simulate_recording(config, trajectory, CLEAN, levels=("centroids", "point_cloud"),
                                 n_frames=600, seed=seed)
        written.append(write_recording(out / f"config_{config}_{trajectory}.h5", rec,
                                       overwrite=True))
    rec = simulate_recording("B", "random",
                             SimulationOptions(physics=None, cube_model=CubeModel(noise_std=4.0, quantize=True)),
                             levels=("centroids", "point_cloud", "cube"), n_frames=4,
                             seed=CUBE_SEED)
    written.append(write_recording(out / "cubes_B_random_4frames.h5", rec, overwrite=True,
                                   cube_storage="int16", compression_opts=4))
    return written


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parent)
    args = ap.parse_args()
    for path in make_samples(args.out):
        print(f"{path} ({path.stat().st_size / 1e6:.2f} MB)")


if __name__ == "__main__":
    main()
