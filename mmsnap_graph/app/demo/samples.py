"""The demo's runs: the sample recordings in ``data/`` or, without them, the
simulator (:mod:`mmsnap_graph.app.demo`).

The sample recordings are named ``config_<A|B|C>_<straight|random>.h5``
(``data/README.md`` of the repository, written by ``data/make_samples.py``).
They are not installed with the package: :func:`find_sample_data` looks in
the working directory's ``data/`` (``pip install . && mmsnap demo`` from the
repository root) and in the ``data/`` next to the package of a source
checkout; without them every run is simulated.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from ...data.recording import Recording
from ...errors import ValidationError
from ...io import read_recording
from ...sim import CLEAN, simulate_recording

__all__ = [
    "CONFIGURATION_NAMES",
    "TRAJECTORY_NAMES",
    "run_seed",
    "sample_path",
    "find_sample_data",
    "truncate_recording",
    "simulate_run",
    "load_run",
]

CONFIGURATION_NAMES = ("A", "B", "C")
TRAJECTORY_NAMES = ("straight", "random")

#: The repository's ``data/`` for a source checkout (``<root>/mmsnap_graph/app/demo/samples.py``).
_CHECKOUT_DATA = Path(__file__).resolve().parents[3] / "data"


def run_seed(seed: int, configuration: str, trajectory: str) -> int:
    """The simulator seed of one run of the demo, derived from its ``seed``."""
    return int(seed) * 1000 + 10 * CONFIGURATION_NAMES.index(configuration) \
        + TRAJECTORY_NAMES.index(trajectory)


def sample_path(data_dir, configuration: str, trajectory: str) -> Path:
    """``<data_dir>/config_<C>_<trajectory>.h5`` (the sample recordings'
    naming, data/README.md)."""
    return Path(data_dir) / f"config_{configuration}_{trajectory}.h5"


def find_sample_data(path=None) -> Path | None:
    """The sample-data folder: ``path`` when given (must exist), else
    ``./data`` or the source checkout's ``data/`` when they hold the samples,
    else None (the demo simulates)."""
    if path is not None:
        p = Path(path)
        if not p.is_dir():
            raise ValidationError(f"data folder {str(p)!r} does not exist")
        return p
    for cand in (Path.cwd() / "data", _CHECKOUT_DATA):
        if sample_path(cand, "C", "straight").is_file():
            return cand
    return None


def truncate_recording(recording: Recording, n_frames: int) -> Recording:
    """The first ``n_frames`` frames of a recording (detections, tracks and
    truth; cubes are dropped)."""
    n = int(n_frames)
    rec = recording
    for node in recording.nodes.values():
        kw = {}
        for level in ("point_cloud", "centroids"):
            d = getattr(node, level)
            if d is not None:
                kw[level] = d.select(d.frame < n)
        if node.tracks is not None:
            kw["tracks"] = node.tracks.select(node.tracks.frame < n)
        rec = rec.with_node(dataclasses.replace(node, cube=None, cube_frame=None, **kw))
    if recording.truth is not None:
        t = recording.truth
        keep = t.frame < n
        rec = dataclasses.replace(rec, truth=dataclasses.replace(
            t, frame=t.frame[keep], target_id=t.target_id[keep], state=t.state[keep]))
    return rec


def simulate_run(configuration: str, trajectory: str, *, n_frames: int, seed: int) -> Recording:
    """A simulated run at the point-cloud level (one walking person), clean
    model: the paper's tables are reproduced on the paper's kind of target."""
    return simulate_recording(configuration, trajectory, CLEAN, levels=("point_cloud",),
                              n_frames=n_frames, seed=run_seed(seed, configuration, trajectory))


def load_run(configuration: str, trajectory: str, *, n_frames: int, seed: int, data_dir=None
             ) -> tuple[Recording, str]:
    """The run's recording and where it came from: the sample file in
    ``data_dir`` when it exists (first ``n_frames`` frames), else simulated."""
    if data_dir is not None:
        path = sample_path(data_dir, configuration, trajectory)
        if path.is_file():
            rec = read_recording(path, load_cubes=False)
            if rec.truth is None:
                raise ValidationError(f"{path} has no truth; the demo needs simulated data")
            return truncate_recording(rec, n_frames), str(path)
    return (simulate_run(configuration, trajectory, n_frames=n_frames, seed=seed),
            f"simulated (seed {run_seed(seed, configuration, trajectory)})")
