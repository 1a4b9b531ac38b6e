"""The end-to-end demo: the paper's experiments on simulated data (``mmsnap demo``).

For each configuration (A, B, C) and each trajectory (straight, random) a
recording of one walking person is simulated, and the paper's protocol is
followed: **calibrate on one trajectory, fuse the other** (the calibration of
the straight run is used to fuse the random run and vice versa).

Levels (stated in every output):

- **raw-cube stretch** (:func:`run_cube_stretch`): a short recording with raw
  ADC cubes goes through the whole per-node chain (range/Doppler/angle FFTs,
  OS-CFAR, torso DBSCAN, EKF) and is fused with the true poses, to show the
  chain end to end; synthesizing and processing 6 runs x 2 nodes x 600 frames
  of cubes would not fit the demo's time budget;
- **the six configuration x trajectory runs** (:func:`run_configuration`)
  start from the simulator's point clouds (its statistical model of the FFT +
  CFAR output, limbs and false alarms included): torso DBSCAN -> per-node EKF
  -> self-calibration (closed form on the EKF tracks, then the joint
  calibration graph, "refined") -> one-shot fusion (Bayesian MAP and ML) with
  the refined poses -> track-level fusion (covariance intersection of the two
  EKF tracks, the paper's benchmark) and the central tracker.

Metrics follow the paper: Table II is the calibration track RMSE (paper eq.
14) per configuration and calibration trajectory; Table III the one-shot
position and velocity RMSE (Bayesian and ML) per configuration and fused
trajectory, against the track-level fusion (as the paper) and against the
ground truth (which the paper did not have), on the frames common to all.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Mapping, Sequence

from tqdm.auto import tqdm

from ..._validation import check_count
from ...errors import CalibrationError, ValidationError
from ...io import read_recording
from ...sim import CLEAN, simulate_recording
from .calibration import CalibrationOutcome, calibrate_run
from .chain import node_chain
from .cubes import CubeStretch, run_cube_stretch
from .fusion import FusionOutcome, fuse_run
from .samples import CONFIGURATION_NAMES, TRAJECTORY_NAMES, load_run, run_seed

__all__ = ["DemoConfig", "DemoResult", "run_configuration", "run_demo", "other_trajectory"]


@dataclass(frozen=True, kw_only=True, slots=True)
class DemoConfig:
    """What the demo runs.

    configurations, trajectories : subsets of ``("A", "B", "C")`` and
        ``("straight", "random")``; the protocol needs both trajectories
        (calibrate on one, fuse the other); with one trajectory the run is
        calibrated and fused on the same data (flagged in the outputs).
    n_frames : frames per run (600 = the paper's 90 s at 150 ms).
    seed : every run's seed derives from it.
    cube_frames : frames of the raw-cube stretch (0: skip it).
    cube_configuration : configuration of the raw-cube stretch.
    max_lag_frames : frame-lag search of the track matching.
    """

    configurations: tuple[str, ...] = CONFIGURATION_NAMES
    trajectories: tuple[str, ...] = TRAJECTORY_NAMES
    n_frames: int = 600
    seed: int = 0
    cube_frames: int = 40
    cube_configuration: str = "C"
    max_lag_frames: int = 2

    def __post_init__(self) -> None:
        confs = tuple(str(c).upper() for c in self.configurations)
        trajs = tuple(str(t) for t in self.trajectories)
        if not confs or any(c not in CONFIGURATION_NAMES for c in confs):
            raise ValidationError(f"configurations={self.configurations!r} must be a non-empty "
                                  f"subset of {CONFIGURATION_NAMES}")
        if not trajs or any(t not in TRAJECTORY_NAMES for t in trajs):
            raise ValidationError(f"trajectories={self.trajectories!r} must be a non-empty "
                                  f"subset of {TRAJECTORY_NAMES}")
        if len(set(confs)) != len(confs) or len(set(trajs)) != len(trajs):
            raise ValidationError("configurations and trajectories must not repeat")
        object.__setattr__(self, "configurations", confs)
        object.__setattr__(self, "trajectories", trajs)
        check_count(self.n_frames, "n_frames", 20)
        check_count(self.cube_frames, "cube_frames", 0)
        if str(self.cube_configuration).upper() not in CONFIGURATION_NAMES:
            raise ValidationError(f"cube_configuration={self.cube_configuration!r} must be one "
                                  f"of {CONFIGURATION_NAMES}")
        object.__setattr__(self, "cube_configuration", str(self.cube_configuration).upper())
        check_count(self.max_lag_frames, "max_lag_frames", 0)

    @property
    def protocol(self) -> str:
        """``"cross"`` (calibrate on one trajectory, fuse the other) or
        ``"same"`` (one trajectory only: calibrate and fuse the same run)."""
        return "cross" if len(self.trajectories) >= 2 else "same"


def other_trajectory(trajectory: str, trajectories: Sequence[str]) -> str:
    """The trajectory whose calibration fuses ``trajectory``: the other one of
    the pair, or itself when only one was run."""
    others = [t for t in trajectories if t != trajectory]
    return others[0] if others else trajectory


@dataclass(frozen=True, kw_only=True, slots=True)
class DemoResult:
    """Everything the demo computed.

    calibrations : (configuration, trajectory) -> :class:`CalibrationOutcome`
        (calibrated on that trajectory). fusions : (configuration, trajectory)
        -> :class:`FusionOutcome` (that trajectory fused with the other's
        calibration). sources : (configuration, trajectory) -> where the run's
        data came from. cube_stretches : the raw-cube runs. seconds : stage ->
        wall time.
    """

    config: DemoConfig
    calibrations: Mapping[tuple[str, str], CalibrationOutcome]
    fusions: Mapping[tuple[str, str], FusionOutcome]
    sources: Mapping[tuple[str, str], str]
    cube_stretches: tuple[CubeStretch, ...]
    seconds: Mapping[str, float]
    failures: tuple[str, ...] = ()

    def to_dict(self) -> dict:
        return {
            "config": {k: (list(v) if isinstance(v, tuple) else v)
                       for k, v in dataclasses.asdict(self.config).items()},
            "protocol": self.config.protocol,
            "sources": {f"{c}/{t}": s for (c, t), s in self.sources.items()},
            "calibration": {f"{c}/{t}": v.to_dict() for (c, t), v in self.calibrations.items()},
            "fusion": {f"{c}/{t}": v.to_dict() for (c, t), v in self.fusions.items()},
            "cube_stretches": [c.to_dict() for c in self.cube_stretches],
            "seconds": dict(self.seconds),
            "failures": list(self.failures),
        }


def _process_runs(configuration: str, config: DemoConfig, data_dir, step):
    """Load (or simulate) every trajectory's run and put it through the
    per-node chain; returns ``(recordings, sources)`` keyed by trajectory."""
    recs, sources = {}, {}
    for traj in config.trajectories:
        step(f"{configuration}/{traj}: DBSCAN torso + EKF")
        rec, src = load_run(configuration, traj, n_frames=config.n_frames, seed=config.seed,
                            data_dir=data_dir)
        recs[traj] = node_chain(rec)
        sources[traj] = src
    return recs, sources


def run_configuration(configuration: str, config: DemoConfig, *, data_dir=None,
                      on_stage: Callable[[str], None] | None = None):
    """Calibrate and fuse both trajectories of one configuration.

    Returns ``(calibrations, fusions, sources, failures)`` keyed by trajectory.
    """
    step = on_stage or (lambda _msg: None)
    recs, sources = _process_runs(configuration, config, data_dir, step)
    cals, fusions, failures = {}, {}, []
    for traj in config.trajectories:
        step(f"{configuration}/{traj}: calibration")
        try:
            cals[traj] = calibrate_run(recs[traj], configuration=configuration, trajectory=traj,
                                       max_lag_frames=config.max_lag_frames)
        except CalibrationError as exc:
            failures.append(f"{configuration}/{traj}: calibration failed: {exc}")
    for traj in config.trajectories:
        cal_traj = other_trajectory(traj, config.trajectories)
        if cal_traj not in cals:
            failures.append(f"{configuration}/{traj}: not fused (no calibration from {cal_traj})")
            continue
        step(f"{configuration}/{traj}: fusion")
        fusions[traj] = fuse_run(recs[traj], cals[cal_traj], configuration=configuration,
                                 trajectory=traj)
    return cals, fusions, sources, failures


def _cube_stretches(config: DemoConfig, cube_recording_paths: Sequence, bar) -> list[CubeStretch]:
    """The raw-cube stretches: each given recording with cubes, then the
    simulated one (``config.cube_frames`` frames, none when 0)."""
    cubes = []
    for path in cube_recording_paths:
        bar.set_postfix_str(f"raw-cube chain: {path}")
        rec = read_recording(path)
        conf = str(rec.metadata.get("network", "?"))
        cubes.append(run_cube_stretch(rec, source=f"sample {Path(path).name}",
                                      configuration=conf))
        bar.update(1)
    if config.cube_frames:
        bar.set_postfix_str(f"raw cubes: {config.cube_configuration}, {config.cube_frames} frames")
        seed = run_seed(config.seed, config.cube_configuration, "straight") + 500
        rec = simulate_recording(config.cube_configuration, "straight", CLEAN, levels=("cube",),
                                 n_frames=config.cube_frames, seed=seed)
        cubes.append(run_cube_stretch(
            rec, source=f"simulated raw ADC cubes (seed {seed})",
            configuration=config.cube_configuration))
        bar.update(1)
    return cubes


def _configurations(config: DemoConfig, data_dir, bar):
    """Every configuration's runs: ``(calibrations, fusions, sources,
    failures)`` keyed by ``(configuration, trajectory)``."""
    cals, fus, srcs, fails = {}, {}, {}, []
    started = [False]

    def stage(msg):
        # Called when a stage starts: the previous one is done.
        if started[0]:
            bar.update(1)
        started[0] = True
        bar.set_postfix_str(msg)

    for conf in config.configurations:
        c, f, s, fl = run_configuration(conf, config, data_dir=data_dir, on_stage=stage)
        cals.update({(conf, t): v for t, v in c.items()})
        fus.update({(conf, t): v for t, v in f.items()})
        srcs.update({(conf, t): v for t, v in s.items()})
        fails.extend(fl)
    if started[0]:
        bar.update(1)
    return cals, fus, srcs, fails


def run_demo(config: DemoConfig | None = None, *, data_dir=None, progress: bool = False,
             cube_recording_paths: Sequence = ()) -> DemoResult:
    """The whole demo (module docstring). ``data_dir``: sample recordings
    (``config_<C>_<trajectory>.h5``) used instead of simulating when present;
    ``cube_recording_paths``: HDF5 recordings with raw cubes to run the full
    chain on, in addition to the simulated cube stretch."""
    config = DemoConfig() if config is None else config
    seconds: dict[str, float] = {}
    n_steps = len(config.configurations) * len(config.trajectories) * 3 + \
        len(cube_recording_paths) + (1 if config.cube_frames else 0)
    bar = tqdm(total=n_steps, desc="mmsnap demo", unit="step", disable=not progress)
    try:
        t0 = time.perf_counter()
        cubes = _cube_stretches(config, cube_recording_paths, bar)
        seconds["raw_cube_chain"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        cals, fus, srcs, fails = _configurations(config, data_dir, bar)
        seconds["configurations"] = time.perf_counter() - t0
    finally:
        bar.close()
    return DemoResult(config=config, calibrations=cals, fusions=fus, sources=srcs,
                      cube_stretches=tuple(cubes), seconds=seconds, failures=tuple(fails))
